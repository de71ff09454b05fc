"""Recipes for the seven UBO2014-like material classes: height field + reflectance maps.

Each recipe builds a tileable :class:`~sparsebtf.data.synth.surface.SurfaceMaps` from a tile
shape, a random generator and a relief factor (1 = the class's natural depth, 0 = flat, which
turns the BTF into a plain SVBRDF — useful to isolate the height-field effects in tests).

Feature sizes scale with the tile (a material is "the same" surface sampled at different
resolutions) but never drop below a few texels, so that even a 16×16 tile still has
resolvable threads, tufts or grains and therefore shadows and parallax. Heights are given as
fractions of that feature size, which keeps shadow lengths and parallax proportionate.

All colours are linear RGB.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from scipy.ndimage import gaussian_filter

from .surface import SurfaceMaps
from .textures import fbm, filtered_noise, photo, smoothstep, standardize, worley

__all__ = ["ALL_CLASSES", "EXTRA_CLASSES", "MATERIAL_CLASSES", "RECIPES", "build_surface"]

MATERIAL_CLASSES = ("carpet", "fabric", "felt", "leather", "stone", "wallpaper", "wood")
#: Classes outside the UBO2014 mirror (not in the benchmark's class list): ``metal`` is a
#: perforated, grooved conductor — masked (exactly black) holes and a high dynamic range.
EXTRA_CLASSES = ("metal",)
ALL_CLASSES = MATERIAL_CLASSES + EXTRA_CLASSES

Shape = tuple[int, int]


def _period(shape: Shape, cells: float, minimum: float = 4.0) -> float:
    """Feature size in texels: ``cells`` features across the shorter side, at least ``minimum``."""
    return max(minimum, min(shape) / cells)


def _counts(shape: Shape, p: float, multiple: int = 1) -> tuple[int, int]:
    """Whole numbers of cells per axis (rows, cols) close to period ``p``, so patterns tile."""
    ny = max(multiple, multiple * round(shape[0] / (p * multiple)))
    nx = max(multiple, multiple * round(shape[1] / (p * multiple)))
    return ny, nx


def _grid(shape: Shape) -> tuple[np.ndarray, np.ndarray]:
    rr, cc = np.mgrid[0 : shape[0], 0 : shape[1]]
    return rr.astype(np.float64), cc.astype(np.float64)


def _pick(rng: np.random.Generator, palettes: list[tuple[tuple[float, ...], ...]]) -> list:
    """One palette, each colour jittered by a few percent (same seed → same colours)."""
    pal = palettes[int(rng.integers(len(palettes)))]
    return [np.asarray(c) * (1.0 + 0.08 * (rng.random(3) - 0.5)) for c in pal]


def _rgb(mask: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Per-texel colour: ``a`` where ``mask`` is 1, ``b`` where it is 0 (blended between)."""
    m = np.asarray(mask, dtype=np.float64)[..., None]
    return m * a + (1.0 - m) * b


def _undulation(
    state: np.ndarray,
    idx_a: np.ndarray,
    idx_b: np.ndarray,
    frac: np.ndarray,
    axis_len: int,
    along_b: bool,
) -> np.ndarray:
    """Smoothly interpolate a per-cell ±1 over/under state along a thread.

    ``state`` is indexed [row cell, col cell]; the thread runs along the cell axis named by
    ``along_b`` (True: column index varies). Half-way across a cell the value is the cell's
    own state, at the border it is the mean with the neighbour, so the yarn dips under the
    crossing thread with a C¹ profile.
    """
    t = frac - 0.5
    step = np.where(t >= 0, 1, -1)
    w = 0.5 * smoothstep(0.0, 0.5, np.abs(t))
    if along_b:
        nb = np.mod(idx_b + step, axis_len)
        return (1 - w) * state[idx_a, idx_b] + w * state[idx_a, nb]
    nb = np.mod(idx_a + step, axis_len)
    return (1 - w) * state[idx_a, idx_b] + w * state[nb, idx_b]


def _fabric(shape: Shape, rng: np.random.Generator, relief: float) -> SurfaceMaps:
    """2/1 twill of round yarns: warp runs along y (rows), weft along x (columns).

    The visible yarn sets the colour and the fibre direction of the anisotropic sheen; yarns
    dip under each other at crossings and leave dark gaps, twisted fibres add fine slant.
    """
    p = _period(shape, 10.0)
    ny, nx = _counts(shape, p, multiple=3)
    rr, cc = _grid(shape)
    uy, ux = rr * ny / shape[0], cc * nx / shape[1]
    j, i = np.floor(uy).astype(int) % ny, np.floor(ux).astype(int) % nx
    fy, fx = uy - np.floor(uy), ux - np.floor(ux)
    jj, ii = np.mgrid[0:ny, 0:nx]
    warp_state = np.where((ii + jj) % 3 != 0, 1.0, -1.0)
    gap = 0.1
    a_warp = np.sqrt(np.clip(1 - ((fx - 0.5) / (0.5 - gap)) ** 2, 0, 1))
    a_weft = np.sqrt(np.clip(1 - ((fy - 0.5) / (0.5 - gap)) ** 2, 0, 1))
    und_warp = _undulation(warp_state, j, i, fy, ny, along_b=False)
    und_weft = _undulation(-warp_state, j, i, fx, nx, along_b=True)
    h_warp = a_warp * (0.55 + 0.45 * und_warp)
    h_weft = a_weft * (0.55 + 0.45 * und_weft)
    warp_top = h_warp >= h_weft
    top = np.maximum(h_warp, h_weft)
    cell_h, cell_w = shape[0] / ny, shape[1] / nx
    # Fibres are twisted round the yarn axis: slanted stripes, a few per cell.
    twist = np.where(
        warp_top,
        np.cos(2 * np.pi * (3 * uy + 0.8 * fx)),
        np.cos(2 * np.pi * (3 * ux + 0.8 * fy)),
    )
    irr_warp = filtered_noise(shape, rng, 0.35 * cell_w, angle=np.pi / 2, stretch=6.0)
    irr_weft = filtered_noise(shape, rng, 0.35 * cell_h, angle=0.0, stretch=6.0)
    irregular = np.where(warp_top, irr_warp, irr_weft)
    fuzz = photo("grass", shape, rng, crop=160)
    height = relief * p * (0.38 * top * (1 + 0.06 * irregular) + 0.025 * twist * top + 0.01 * fuzz)
    warp_c, weft_c = _pick(
        rng,
        [
            ((0.03, 0.06, 0.20), (0.55, 0.55, 0.50)),  # denim
            ((0.30, 0.03, 0.05), (0.45, 0.30, 0.20)),  # burgundy / camel
            ((0.12, 0.16, 0.05), (0.40, 0.36, 0.20)),  # olive / khaki
        ],
    )
    shade = (0.7 + 0.3 * top) * (1 + 0.07 * irregular + 0.05 * twist + 0.04 * fuzz)
    depth = 0.35 + 0.65 * smoothstep(0.0, 0.35, top)
    albedo = _rgb(warp_top, warp_c, weft_c) * (shade * depth)[..., None]
    return SurfaceMaps(
        height=height,
        albedo=albedo,
        specular=np.full(3, 0.04),
        roughness=0.5 + 0.05 * irregular,
        sheen=0.35 * smoothstep(0.0, 0.3, top),
        fibre_angle=np.where(warp_top, np.pi / 2, 0.0),
        sheen_model="fibre",
        penumbra=0.14,
        period=p,
    )


def _carpet(shape: Shape, rng: np.random.Generator, relief: float) -> SurfaceMaps:
    """Berber loop pile: rows of tall yarn loops in brick bond with deep gaps and flecks."""
    p = _period(shape, 8.0, minimum=5.0)
    ny, nx = _counts(shape, p, multiple=2)
    rr, cc = _grid(shape)
    uy = rr * ny / shape[0]
    j = np.floor(uy).astype(int) % ny
    ux = cc * nx / shape[1] + 0.5 * (j % 2)
    i = np.floor(ux).astype(int) % nx
    fy, fx = uy - np.floor(uy), ux - np.floor(ux)
    d2 = ((fx - 0.5) / 0.47) ** 2 + ((fy - 0.5) / 0.40) ** 2
    loop = np.sqrt(np.clip(1 - d2, 0, 1)) ** 0.7
    # Each loop is a plied yarn: slanted twist ridges across it.
    twist = np.cos(2 * np.pi * (4 * fx + 1.5 * fy)) * smoothstep(0.0, 0.3, loop)
    fibres = photo("grass", shape, rng, crop=96)
    strands = filtered_noise(shape, rng, max(0.6, 0.05 * p), angle=np.pi / 2, stretch=4.0)
    height = relief * p * (0.38 * loop * (1 + 0.08 * fibres) + 0.03 * strands + 0.025 * twist)
    base, fleck = _pick(
        rng,
        [
            ((0.45, 0.38, 0.28), (0.10, 0.08, 0.06)),  # oatmeal berber
            ((0.30, 0.30, 0.32), (0.05, 0.05, 0.06)),  # grey
            ((0.07, 0.11, 0.25), (0.40, 0.40, 0.42)),  # navy
        ],
    )
    is_fleck = rng.random((ny, nx)) < 0.2
    # Dyed loops are flecked; the backing between loops keeps the base colour.
    albedo = _rgb(is_fleck[j, i] * smoothstep(0.0, 0.3, loop), fleck, base)
    shade = (0.4 + 0.6 * loop) * (1 + 0.12 * fibres + 0.08 * strands + 0.1 * twist)
    albedo = albedo * shade[..., None]
    return SurfaceMaps(
        height=height,
        albedo=albedo,
        specular=np.full(3, 0.03),
        roughness=np.full(shape, 0.85),
        sheen=np.full(shape, 0.15),
        fibre_angle=np.zeros(shape),
        sheen_model="velvet",
        penumbra=0.2,
        period=p,
    )


def _felt(shape: Shape, rng: np.random.Generator, relief: float) -> SurfaceMaps:
    """Pressed wool: a gently lumpy mat of short, randomly oriented fuzzy fibres."""
    p = _period(shape, 6.0)
    fine = max(0.7, 0.05 * p)  # fibre width: resolved, and scaling with the tile like p
    lumps = fbm(shape, rng, 0.5 * p, octaves=4)
    # Fibre orientations spread evenly (with jitter): pressed felt has no grain direction.
    angles = np.pi * (np.arange(8) + rng.uniform(0, 1, 8)) / 8
    layers = np.stack(
        [filtered_noise(shape, rng, fine, angle=float(a), stretch=4.0) for a in angles]
    )
    # A soft maximum over randomly oriented fibre layers: crossing fibres, no hard ridges.
    fibres = standardize(np.log(np.sum(np.exp(1.5 * layers), axis=0)))
    height = relief * p * (0.05 * lumps + 0.025 * fibres)
    (color,) = _pick(
        rng,
        [
            ((0.45, 0.04, 0.04),),  # red
            ((0.05, 0.18, 0.06),),  # forest green
            ((0.09, 0.09, 0.10),),  # charcoal
            ((0.55, 0.35, 0.05),),  # mustard
        ],
    )
    albedo = color * np.clip(0.85 + 0.08 * lumps + 0.08 * fibres, 0.5, 1.2)[..., None]
    return SurfaceMaps(
        height=height,
        albedo=albedo,
        specular=np.full(3, 0.02),
        roughness=np.full(shape, 0.9),
        sheen=0.45 + 0.05 * fibres,
        fibre_angle=np.zeros(shape),
        sheen_model="velvet",
        penumbra=0.3,
        period=p,
    )


def _leather(shape: Shape, rng: np.random.Generator, relief: float) -> SurfaceMaps:
    """Pebble-grain leather: domed grains between creases (Worley cells) and small pores."""
    p = _period(shape, 7.0)
    n_cells = max(4, round(shape[0] * shape[1] / (p * p)))
    f1, f2, _ = worley(shape, rng, n_cells)
    dome = smoothstep(0.0, 0.4 * p, f2 - f1)
    density = 1.5 / (p * p) + 0.01
    pits = (rng.random(shape) < density).astype(np.float64)
    pores = gaussian_filter(pits, sigma=max(0.7, 0.05 * p), mode="wrap")
    pores = pores / max(float(pores.max()), 1e-9)
    wrinkles = fbm(shape, rng, 0.6 * p, octaves=3)
    mottle = photo("gravel", shape, rng, crop=200)
    height = relief * p * (0.16 * dome - 0.10 * pores + 0.03 * wrinkles)
    (color,) = _pick(
        rng,
        [
            ((0.28, 0.12, 0.05),),  # saddle brown
            ((0.035, 0.03, 0.03),),  # black
            ((0.50, 0.32, 0.18),),  # tan
            ((0.20, 0.03, 0.035),),  # oxblood
        ],
    )
    shade = (0.65 + 0.35 * dome) * (1 + 0.08 * mottle) * (1 - 0.45 * pores)
    albedo = color * shade[..., None]
    return SurfaceMaps(
        height=height,
        albedo=albedo,
        specular=np.full(3, 0.045),
        roughness=0.55 - 0.22 * dome + 0.03 * mottle,
        sheen=np.zeros(shape),
        fibre_angle=np.zeros(shape),
        sheen_model="none",
        penumbra=0.1,
        period=p,
    )


def _stone(shape: Shape, rng: np.random.Generator, relief: float) -> SurfaceMaps:
    """Rough stone: mineral grains (gravel photo), cell-wise tint and thin deep cracks."""
    p = _period(shape, 5.0, minimum=5.0)
    n_cells = max(4, round(shape[0] * shape[1] / (p * p)))
    f1, f2, site = worley(shape, rng, n_cells)
    crack_w = 0.04 * p + 0.35
    cracks = np.exp(-(((f2 - f1) / crack_w) ** 2))
    grains = photo("gravel", shape, rng, crop=192)
    fine = photo("brick", shape, rng, crop=96)
    lift = rng.normal(size=n_cells)[site]
    height = relief * p * (0.035 * grains + 0.01 * fine + 0.03 * lift - 0.12 * cracks)
    (base,) = _pick(
        rng,
        [
            ((0.32, 0.30, 0.28),),  # granite grey
            ((0.45, 0.33, 0.22),),  # sandstone
            ((0.13, 0.14, 0.15),),  # slate
        ],
    )
    # Grains differ mostly in lightness, a little in hue (mixed minerals).
    tint = (0.7 + 0.6 * rng.random((n_cells, 1))) * (1 + 0.15 * (rng.random((n_cells, 3)) - 0.5))
    shade = (1 + 0.2 * grains + 0.06 * fine) * (1 - 0.65 * cracks)
    albedo = base * tint[site] * np.clip(shade, 0.05, None)[..., None]
    return SurfaceMaps(
        height=height,
        albedo=albedo,
        specular=np.full(3, 0.04),
        roughness=np.clip(0.6 + 0.08 * fine, 0.3, 1.0),
        sheen=np.zeros(shape),
        fibre_angle=np.zeros(shape),
        sheen_model="none",
        penumbra=0.1,
        period=p,
    )


def _wallpaper(shape: Shape, rng: np.random.Generator, relief: float) -> SurfaceMaps:
    """Printed wallpaper: a rosette-and-lattice print (metallic ink) on embossed paper."""
    motif = _period(shape, 3.0, minimum=10.0)
    p = _period(shape, 12.0)
    ny, nx = _counts(shape, motif)
    rr, cc = _grid(shape)
    uy, ux = rr * ny / shape[0], cc * nx / shape[1]
    dy, dx = uy - np.floor(uy) - 0.5, ux - np.floor(ux) - 0.5
    px_per_cell = min(shape[0] / ny, shape[1] / nx)
    aa = 0.8 / px_per_cell  # anti-aliased print edges, ~1 texel wide
    r = np.hypot(dx, dy)
    ang = np.arctan2(dy, dx)
    petals = 0.28 * (0.72 + 0.28 * np.cos(6 * ang))
    rosette = smoothstep(aa, -aa, r - petals) - smoothstep(aa, -aa, r - 0.07)
    lattice = smoothstep(aa, -aa, np.abs(np.abs(dx) + np.abs(dy) - 0.5) - 0.025)
    dots = smoothstep(aa, -aa, np.hypot(np.abs(dx) - 0.5, np.abs(dy) - 0.5) - 0.06)
    gold = np.clip(rosette + dots, 0, 1)
    ink = np.clip(lattice * (1 - gold), 0, 1)
    paper = photo("grass", shape, rng, crop=64)
    linen = standardize(
        filtered_noise(shape, rng, max(0.7, 0.08 * p), angle=0.0, stretch=6.0)
        + filtered_noise(shape, rng, max(0.7, 0.08 * p), angle=np.pi / 2, stretch=6.0)
    )
    height = relief * p * (0.22 * gold + 0.12 * ink + 0.05 * linen + 0.03 * paper)
    bg, ink_c = _pick(
        rng,
        [
            ((0.70, 0.64, 0.48), (0.30, 0.05, 0.06)),  # cream / burgundy
            ((0.33, 0.42, 0.30), (0.05, 0.08, 0.05)),  # sage / bottle green
            ((0.05, 0.07, 0.16), (0.55, 0.52, 0.45)),  # navy / stone
        ],
    )
    gold_albedo = np.array([0.10, 0.07, 0.03])
    gold_f0 = np.array([0.85, 0.62, 0.28])
    paper_shade = (1 + 0.05 * paper + 0.03 * linen)[..., None]
    albedo = _rgb(gold, gold_albedo, _rgb(ink, ink_c, bg)) * paper_shade
    specular = _rgb(gold, gold_f0, np.full(3, 0.035))
    return SurfaceMaps(
        height=height,
        albedo=albedo,
        specular=specular,
        roughness=0.65 - 0.4 * gold - 0.2 * ink,
        sheen=np.zeros(shape),
        fibre_angle=np.zeros(shape),
        sheen_model="none",
        penumbra=0.1,
        period=p,
    )


def _wood(shape: Shape, rng: np.random.Generator, relief: float) -> SurfaceMaps:
    """Varnished flat-sawn wood: growth rings along x, dark latewood, open pores, figure."""
    p = _period(shape, 8.0, minimum=5.0)
    n_rings, _ = _counts(shape, p)
    rr, cc = _grid(shape)
    # A flat-sawn board cuts the annual rings at a slant: they bend into arches ("cathedrals").
    phase = rng.uniform(0, 2 * np.pi)
    arch = 0.6 * np.cos(np.pi * cc / shape[1] + phase / 2) ** 2
    wobble = filtered_noise(shape, rng, 0.15 * min(shape), angle=0.0, stretch=3.0)
    detail = filtered_noise(shape, rng, 0.03 * min(shape) + 1.0, angle=0.0, stretch=5.0)
    s = n_rings * rr / shape[0] + arch + 0.5 * wobble + 0.06 * detail
    g = s - np.floor(s)
    late = smoothstep(0.55, 0.88, g) * (1 - smoothstep(0.94, 1.0, g))
    # Ring-porous wood: long open vessels, mostly in the earlywood.
    pore_noise = filtered_noise(shape, rng, max(0.5, 0.04 * p), angle=0.0, stretch=18.0)
    pores = smoothstep(1.4, 2.4, pore_noise) * (1 - 0.7 * late)
    lines = filtered_noise(shape, rng, max(0.45, 0.035 * p), angle=0.0, stretch=25.0)
    figure = photo("grass", shape, rng, crop=128, stretch=(4.0, 1.0))
    height = relief * p * (0.04 * late - 0.08 * pores + 0.006 * lines + 0.004 * figure)
    early_c, late_c = _pick(
        rng,
        [
            ((0.50, 0.30, 0.15), (0.26, 0.13, 0.055)),  # oak
            ((0.22, 0.12, 0.06), (0.08, 0.04, 0.02)),  # walnut
            ((0.55, 0.38, 0.18), (0.38, 0.18, 0.06)),  # pine
        ],
    )
    shade = (1 + 0.06 * lines + 0.05 * figure) * (1 - 0.5 * pores)
    albedo = _rgb(late, late_c, early_c) * shade[..., None]
    return SurfaceMaps(
        height=height,
        albedo=albedo,
        specular=np.full(3, 0.05),
        roughness=0.22 + 0.25 * pores + 0.01 * lines,
        sheen=np.zeros(shape),
        fibre_angle=np.zeros(shape),
        sheen_model="none",
        penumbra=0.08,
        period=p,
    )


def _metal(shape: Shape, rng: np.random.Generator, relief: float) -> SurfaceMaps:
    """Perforated brushed metal: V-grooves along the rows, brushing streaks, and a staggered
    grid of punched holes that reflect nothing (masked texels, exactly black)."""
    p = _period(shape, 4.0, minimum=6.0)
    rr, cc = _grid(shape)
    ny, nx = _counts(shape, p)
    py, px = shape[0] / ny, shape[1] / nx
    # V-grooves: |saw| profile across rows, one per cell row, half a cell deep.
    groove = np.abs(np.mod(rr / py, 1.0) - 0.5)
    streaks = filtered_noise(shape, rng, 0.6, angle=0.0, stretch=12.0)
    # Holes centred in every other groove ridge, staggered by half a cell.
    cy = (np.floor(rr / py) + 0.5) * py
    shift = np.where(np.mod(np.floor(rr / py), 2) == 0, 0.0, 0.5)
    cx = (np.floor(cc / px - shift) + 0.5 + shift) * px
    dist = np.hypot(rr - cy, np.mod(cc - cx + shape[1] / 2, shape[1]) - shape[1] / 2)
    hole = dist < 0.2 * min(py, px)
    height = relief * p * (0.25 * groove + 0.01 * streaks - 0.3 * hole)
    (f0,) = _pick(
        rng,
        [
            ((1.0, 0.78, 0.34),),  # gold
            ((0.95, 0.64, 0.54),),  # copper
            ((0.56, 0.57, 0.58),),  # steel
        ],
    )
    return SurfaceMaps(
        height=height,
        albedo=np.zeros(3),
        specular=f0,
        roughness=np.clip(0.18 + 0.04 * streaks, 0.1, 0.3),
        sheen=np.zeros(shape),
        fibre_angle=np.zeros(shape),
        sheen_model="none",
        penumbra=0.05,
        period=p,
        mask=~hole,
    )


RECIPES: dict[str, Callable[[Shape, np.random.Generator, float], SurfaceMaps]] = {
    "carpet": _carpet,
    "fabric": _fabric,
    "felt": _felt,
    "leather": _leather,
    "stone": _stone,
    "wallpaper": _wallpaper,
    "wood": _wood,
    "metal": _metal,
}


def build_surface(material: str, shape: Shape, seed: int, relief: float = 1.0) -> SurfaceMaps:
    """The maps of ``material`` for a tile of ``shape`` texels, deterministic in ``seed``.

    The class name is mixed into the seed so that e.g. stone and leather with the same seed
    do not share their random draws.
    """
    class_id = ALL_CLASSES.index(material)
    rng = np.random.default_rng([int(seed), class_id])
    return RECIPES[material](shape, rng, float(relief))

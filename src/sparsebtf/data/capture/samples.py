"""Built-in samples for ``sparsebtf capture``: material micro-geometry made of Mitsuba shapes,
meshes and textures, each a pure function of its seed.

Every sample describes one period on the tile x, y ∈ [−1, 1] around z = 0 (:mod:`.geometry`)
and tiles seamlessly (threads, grooves and height maps are periodic; pebbles that cross an edge
continue in the neighbouring copy). Colours are linear RGB.

* ``plane`` — the calibration target: a flat diffuse chart of 4×4 patches of seeded albedos.
* ``woven`` — plain weave: four warp and four weft threads, elliptic tubes going over and
  under each other, rough dielectric-coated dyed fibres (``roughplastic``) over a dark backing.
* ``pebbles`` — displaced, flattened spheres half sunk in a sandy diffuse ground, rough
  plastic of seeded colours.
* ``leather`` — embossed leather: a displaced mesh from a cellular height map (grain cells and
  creases), rough plastic with a darker crease texture.
* ``metal`` — brushed metal with V grooves: a grooved mesh, anisotropic rough conductor
  brushed along x.
* ``copper`` — glossy bumpy copper: a smooth periodic height field (four seeded sinusoids
  of whole periods, heights ±0.3), an isotropic GGX conductor of roughness α = 0.15. Narrow
  highlights next to hard shadows (at 20×20 texels, 1 spp: 21 % exact zeros, 7.9 % of the
  values above 1, the largest 66): the case of a coding objective in linear RGB.
* ``copper-mirror`` — the ``copper`` height field with a near-mirror isotropic GGX conductor,
  α = 0.05 (at 20×20 texels, 1 spp: 21 % exact zeros, 3.5 % of the values above 1,
  the largest 776).
* ``copper-rough`` — the ``copper`` height field with a rougher isotropic GGX conductor,
  α = 0.3 (at 20×20 texels, 1 spp: 21 % exact zeros, 8.6 % of the values above 1,
  the largest 11.5).
* ``brushed`` — glossy brushed aluminium: a gentler smooth height field of the same kind (its
  own seed stream, heights ±0.2), an anisotropic GGX conductor brushed along x, α = 0.03 along
  the brushing and 0.2 across; the smooth glossy counterpart of the grooved ``metal`` (at
  20×20 texels, 1 spp: 18 % exact zeros, 6.1 % of the values above 1, the largest 591).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..meshes import grid_faces, mesh_object, sphere_mesh

__all__ = ["SAMPLES", "Sample", "heightfield_mesh"]

MeshArrays = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]


@dataclass(frozen=True)
class Sample:
    """A built-in sample: ``build(seed)`` returns its ``mi.Load_dict`` scene dictionary."""

    name: str
    description: str
    build: Callable[[int], dict[str, Any]]


# --------------------------------------------------------------------------- mesh helpers


def _orient(pos: np.ndarray, normals: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """``faces`` wound so that each face's geometric normal agrees with its vertex normals."""
    p = pos[faces]
    face_n = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    flip = np.einsum("ij,ij->i", face_n, normals[faces].sum(axis=1)) < 0
    out = faces.copy()
    out[flip] = out[flip][:, ::-1]
    return out


def heightfield_mesh(height: np.ndarray, z_scale: float = 1.0) -> MeshArrays:
    """(positions, normals, uv, faces) of a periodic height map over the tile.

    ``height`` (N, N) is in image order: entry [r, c] is the height of the point
    x = −1 + (c + ½)·2/N, y = 1 − (r + ½)·2/N (a texel centre of an N×N capture), times
    ``z_scale``. The grid has N + 1 vertices per side (the first row and column repeat), so
    copies of the tile join without a gap; normals come from periodic central differences.
    """
    h = np.asarray(height, dtype=np.float64) * z_scale
    n_r, n_c = h.shape
    sy, sx = 2.0 / n_r, 2.0 / n_c
    rr, cc = np.mgrid[0 : n_r + 1, 0 : n_c + 1]
    z = h[rr % n_r, cc % n_c]
    dz_dx = (np.roll(h, -1, 1) - np.roll(h, 1, 1)) / (2 * sx)
    dz_dy = -(np.roll(h, -1, 0) - np.roll(h, 1, 0)) / (2 * sy)  # rows run against +y
    nrm = np.stack([-dz_dx, -dz_dy, np.ones_like(h)], -1)
    nrm /= np.linalg.norm(nrm, axis=-1, keepdims=True)
    x = -1.0 + (cc + 0.5) * sx
    y = 1.0 - (rr + 0.5) * sy
    pos = np.stack([x, y, z], -1).reshape(-1, 3)
    normals = nrm[rr % n_r, cc % n_c].reshape(-1, 3)
    uv = np.stack([(x + 1) / 2, (y + 1) / 2], -1).reshape(-1, 2)
    faces = _orient(pos, normals, grid_faces(n_c, n_r))
    return pos, normals, uv, faces


def _tube(centre: Callable[[np.ndarray], np.ndarray], across: np.ndarray, half_width: float,
          half_height: float, n_along: int = 64, n_around: int = 16) -> MeshArrays:  # fmt: skip
    """An elliptic tube along the curve ``centre(t)`` (t ∈ [0, 1] → (n, 3)), its wide axis
    along the horizontal unit vector ``across``."""
    t = np.linspace(0.0, 1.0, n_along + 1)
    c = centre(t)
    tangent = np.gradient(c, t, axis=0)
    tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
    b = np.broadcast_to(across, c.shape)
    up = np.cross(tangent, b)
    up /= np.linalg.norm(up, axis=1, keepdims=True) * np.sign(up[:, 2:3])
    phi = np.linspace(0.0, 2 * np.pi, n_around + 1)
    cp, sp = np.cos(phi)[None, :, None], np.sin(phi)[None, :, None]
    pos = c[:, None] + half_width * cp * b[:, None] + half_height * sp * up[:, None]
    nrm = cp / half_width * b[:, None] + sp / half_height * up[:, None]
    nrm /= np.linalg.norm(nrm, axis=-1, keepdims=True)
    uv = np.stack(np.meshgrid(phi / (2 * np.pi), t)[::-1], -1)
    pos, nrm, uv = pos.reshape(-1, 3), nrm.reshape(-1, 3), uv.reshape(-1, 2)
    faces = _orient(pos, nrm, grid_faces(n_around, n_along))
    return pos, nrm, uv, faces


def _bitmap(image: np.ndarray, nearest: bool = False) -> dict[str, Any]:
    """A linear-RGB, repeating bitmap texture from an (H, W, 3) array in [0, 1]."""
    import mitsuba as mi

    arr = np.ascontiguousarray(np.clip(image, 0.0, 1.0), dtype=np.float32)
    return {"type": "bitmap", "bitmap": mi.Bitmap(arr), "raw": True, "wrap_mode": "repeat",
            "filter_type": "nearest" if nearest else "bilinear"}  # fmt: skip


def _rgb(value: Any) -> dict[str, Any]:
    return {"type": "rgb", "value": [float(v) for v in np.broadcast_to(value, 3)]}


def _mesh(name: str, arrays: MeshArrays, bsdf: dict[str, Any]) -> Any:
    import mitsuba as mi

    return mesh_object(mi, name, arrays, bsdf)


def _ground(z: float, colour: Any) -> dict[str, Any]:
    """A diffuse rectangle filling the tile at height ``z``."""
    import mitsuba as mi

    return {"type": "rectangle", "to_world": mi.ScalarTransform4f().translate([0.0, 0.0, z]),
            "bsdf": {"type": "diffuse", "reflectance": _rgb(colour)}}  # fmt: skip


# --------------------------------------------------------------------------- the samples


def chart_albedo(seed: int, patches: int = 4) -> np.ndarray:
    """The ``plane`` sample's albedo chart: (patches, patches, 3) linear RGB in [0.05, 0.9],
    row 0 at the top (+y) of the tile."""
    rng = np.random.default_rng([seed, 1])
    return rng.uniform(0.05, 0.9, (patches, patches, 3))


def _plane(seed: int) -> dict[str, Any]:
    chart = chart_albedo(seed)
    chart = chart[::-1]  # Mitsuba puts bitmap row 0 at v = 0, the bottom (−y) of the tile
    return {"type": "scene", "chart": {
        "type": "rectangle", "bsdf": {"type": "diffuse", "reflectance": _bitmap(chart, True)}}}


def _woven(seed: int) -> dict[str, Any]:
    rng = np.random.default_rng([seed, 2])
    n = 4
    s = 2.0 / n
    half_h = 0.16 * s
    amp = 1.05 * half_h
    palettes = [((0.03, 0.06, 0.20), (0.55, 0.55, 0.50)), ((0.30, 0.03, 0.05), (0.45, 0.30, 0.2)),
                ((0.12, 0.16, 0.05), (0.40, 0.36, 0.20))]  # fmt: skip
    warp_c, weft_c = palettes[int(rng.integers(len(palettes)))]
    d: dict[str, Any] = {"type": "scene", "backing": _ground(-(amp + half_h) - 0.02, 0.03)}
    for i in range(n):
        off = -1.0 + (i + 0.5) * s
        for kind, colour in (("warp", warp_c), ("weft", weft_c)):
            sign = 1.0 if kind == "warp" else -1.0
            jitter = 1.0 + 0.08 * (rng.random(3) - 0.5)

            def centre(t: np.ndarray, off: float = off, sign: float = sign,
                       kind: str = kind, i: int = i) -> np.ndarray:  # fmt: skip
                along = -1.0 + 2.0 * t
                z = sign * amp * np.cos(np.pi * ((along + 1) / s - 0.5) + np.pi * i)
                other = np.full_like(t, off)
                if kind == "warp":  # runs along y
                    return np.stack([other, along, z], -1)
                return np.stack([along, other, z], -1)

            across = np.array([1.0, 0.0, 0.0]) if kind == "warp" else np.array([0.0, 1.0, 0.0])
            bsdf = {"type": "roughplastic", "distribution": "ggx", "alpha": 0.3,
                    "diffuse_reflectance": _rgb(np.clip(np.array(colour) * jitter, 0, 1))}
            arrays = _tube(centre, across, 0.42 * s, half_h)
            d[f"{kind}{i}"] = _mesh(f"{kind}{i}", arrays, bsdf)
    return d


def _pebbles(seed: int) -> dict[str, Any]:
    rng = np.random.default_rng([seed, 3])
    d: dict[str, Any] = {"type": "scene",
                         "ground": _ground(0.0, 0.45 * np.array([1.0, 0.9, 0.75]))}
    centres: list[np.ndarray] = []
    for _ in range(400):  # dart throwing with periodic distances
        if len(centres) == 9:
            break
        c, r = rng.uniform(-1, 1, 2), rng.uniform(0.22, 0.4)
        if all(np.linalg.norm((c - q[:2] + 1) % 2 - 1) > 0.85 * (r + q[2]) for q in centres):
            centres.append(np.array([*c, r]))
    for k, (cx, cy, r) in enumerate(centres):
        pos, nrm, uv, faces = sphere_mesh((0.0, 0.0, 0.0), 1.0, n_lon=48, n_lat=24)
        pos = pos[:, [0, 2, 1]] * np.array([1.0, -1.0, 1.0])  # y-up → z-up (a rotation)
        g = rng.normal(size=(6, 3))
        bump = sum(np.sin(3.0 * pos @ gk + rng.uniform(0, 2 * np.pi)) for gk in g) / 6
        radial = r * (1.0 + 0.12 * bump)
        squash = np.array([1.0, rng.uniform(0.75, 1.0), 0.55])
        pos = pos * radial[:, None] * squash + np.array([cx, cy, 0.1 * r])
        nrm = _vertex_normals(pos, faces)
        colour = rng.uniform(0.15, 0.6) * (1.0 + 0.25 * (rng.random(3) - 0.5))
        bsdf = {"type": "roughplastic", "distribution": "ggx",
                "alpha": float(rng.uniform(0.12, 0.3)), "diffuse_reflectance": _rgb(colour)}
        d[f"pebble{k}"] = _mesh(f"pebble{k}", (pos, nrm, uv, _orient(pos, nrm, faces)), bsdf)
    return d


def _vertex_normals(pos: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Area-weighted vertex normals of an outward-wound closed mesh (pointing outwards)."""
    p = pos[faces]
    fn = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    centre = pos.mean(axis=0)
    out_sign = np.sign(np.einsum("ij,ij->i", fn, p.mean(axis=1) - centre))
    fn *= np.where(out_sign == 0, 1.0, out_sign)[:, None]
    acc = np.zeros_like(pos)
    for k in range(3):
        np.add.at(acc, faces[:, k], fn)
    return acc / np.maximum(np.linalg.norm(acc, axis=1, keepdims=True), 1e-12)


def _leather(seed: int) -> dict[str, Any]:
    from ..synth.textures import fbm, smoothstep, worley

    rng = np.random.default_rng([seed, 4])
    n = 128
    f1, f2, _ = worley((n, n), rng, 40)
    crease = smoothstep(0.0, 2.5, f2 - f1)  # 0 in the creases between grain cells
    dome = 1.0 - smoothstep(0.0, 9.0, f1)
    grain = fbm((n, n), rng, 1.5, octaves=3)
    height = 0.6 * crease + 0.25 * dome + 0.05 * grain
    height -= height.mean()
    base = np.array([0.30, 0.13, 0.06]) * (1.0 + 0.1 * (rng.random(3) - 0.5))
    shade = (0.55 + 0.45 * crease) * (1.0 + 0.08 * grain)
    albedo = base[None, None, :] * shade[..., None]
    bsdf = {"type": "roughplastic", "distribution": "ggx", "alpha": 0.35,
            "diffuse_reflectance": _bitmap(albedo)}
    return {"type": "scene", "leather": _mesh("leather", heightfield_mesh(height, 0.08), bsdf)}


def _metal(seed: int) -> dict[str, Any]:
    from ..synth.textures import filtered_noise

    rng = np.random.default_rng([seed, 5])
    n = 128
    rows = np.arange(n) + 0.5
    profile = np.zeros(n)
    for centre in rng.choice(n, size=int(rng.integers(3, 6)), replace=False):
        width = rng.uniform(5.0, 9.0)
        dist = np.abs((rows - centre + n / 2) % n - n / 2)
        profile = np.minimum(profile, -np.clip(1.0 - dist / width, 0.0, None))
    brushing = filtered_noise((n, n), rng, 0.8, angle=0.0, stretch=12.0)
    height = profile[:, None] * 0.06 + 0.002 * brushing  # grooves run along x (image rows)
    metal = ["Al", "Cu", "Au", "Cr"][int(rng.integers(4))]
    bsdf = {"type": "roughconductor", "distribution": "ggx", "material": metal,
            "alpha_u": 0.04, "alpha_v": 0.25}  # brushed along u = +x: rough across the brush
    return {"type": "scene", "metal": _mesh("metal", heightfield_mesh(height), bsdf)}


def copper_height(seed: int, n: int = 128, stream: int = 6) -> np.ndarray:
    """The ``copper`` sample's height map: (n, n), zero-mean, a sum of four seeded periodic
    sinusoids of 1–3 whole periods per tile (smooth bumps, slopes up to ~0.5), scaled to a
    largest height of 1. ``stream`` picks the random stream (6: ``copper`` and its variants;
    7: ``brushed``)."""
    rng = np.random.default_rng([seed, stream])
    t = (np.arange(n) + 0.5) / n
    yy, xx = np.meshgrid(t, t, indexing="ij")
    height = np.zeros((n, n))
    for _ in range(4):
        fx, fy = rng.integers(1, 4, 2) * rng.choice([-1, 1], 2)
        phase = rng.uniform(0, 2 * np.pi)
        height += rng.uniform(0.5, 1.0) * np.cos(2 * np.pi * (fx * xx + fy * yy) + phase)
    height -= height.mean()
    return height / np.abs(height).max()


def _copper_alpha(alpha: float) -> Callable[[int], dict[str, Any]]:
    """The ``copper`` height field (heights ±0.3) with an isotropic GGX copper of ``alpha``."""

    def build(seed: int) -> dict[str, Any]:
        bsdf = {"type": "roughconductor", "distribution": "ggx", "material": "Cu",
                "alpha": alpha}  # fmt: skip
        return {"type": "scene",
                "copper": _mesh("copper", heightfield_mesh(copper_height(seed), 0.3), bsdf)}

    return build


_copper = _copper_alpha(0.15)


def _brushed(seed: int) -> dict[str, Any]:
    bsdf = {"type": "roughconductor", "distribution": "ggx", "material": "Al",
            "alpha_u": 0.03, "alpha_v": 0.2}  # brushed along u = +x: rough across the brush
    height = copper_height(seed, stream=7)
    return {"type": "scene", "brushed": _mesh("brushed", heightfield_mesh(height, 0.2), bsdf)}


SAMPLES: dict[str, Sample] = {
    s.name: s
    for s in (
        Sample("plane", "calibration target: flat diffuse chart of 4x4 seeded albedos", _plane),
        Sample("woven", "plain weave of rough dielectric-coated threads over a dark backing",
               _woven),
        Sample("pebbles", "displaced flattened spheres of rough plastic in diffuse sand",
               _pebbles),
        Sample("leather", "embossed leather: displaced mesh from a cellular height map",
               _leather),
        Sample("metal", "brushed metal with V grooves: anisotropic rough conductor", _metal),
        Sample("copper", "glossy bumpy copper: smooth height field, isotropic GGX conductor "
               "(alpha 0.15)", _copper),
        Sample("copper-mirror", "near-mirror bumpy copper: the copper height field, isotropic "
               "GGX conductor (alpha 0.05)", _copper_alpha(0.05)),
        Sample("copper-rough", "rough bumpy copper: the copper height field, isotropic GGX "
               "conductor (alpha 0.3)", _copper_alpha(0.3)),
        Sample("brushed", "glossy brushed aluminium: smooth height field, anisotropic GGX "
               "conductor (alpha 0.03 along x, 0.2 across)", _brushed),
    )
}

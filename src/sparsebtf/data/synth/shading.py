"""Rendering a height-field material into BTF values: shadows, parallax, masking, reflectance.

The physical model, per texel of the rectified image, light ω_i and view ω_o:

1. **Parallax and masking.** Measured BTF images are rectified onto a reference plane (here
   the mean height). The camera ray through a reference-plane texel u meets the height field
   at its *first* hit, found by marching the ray from the top of the relief downwards
   (parallax occlusion mapping). The visible surface point is u + h·tan θ_o·(cos φ_o,
   sin φ_o); points hidden behind taller relief are never seen (masking). All maps are then
   read at that point with bilinear, wrap-around lookups.
2. **Self-shadowing.** For every light azimuth a horizon map gives, per surface point, the
   elevation of the highest relief along the light's direction; the light is visible when its
   elevation clears the horizon. A linear ramp of half width ``penumbra`` (a few degrees)
   around the horizon gives the soft shadow edges of an extended light and sub-texel detail.
3. **Reflectance.** Lambertian diffuse + GGX microfacet specular (Smith masking-shadowing,
   Schlick Fresnel, per-channel F0), plus a cloth sheen where the class has one: an
   anisotropic Kajiya–Kay fibre highlight, or a velvet lobe ("Charlie" sheen with a
   retro-reflective hot spot from shadow hiding in the fibre pile).
4. **Foreshortening.** As in measured data the value is reflected radiance over the
   irradiance of a light facing the sample: it includes cos θ_i (the local n·ω_i for direct
   light) but not cos θ_o. Values are in reflectance units (π·f_r·cos θ_i; a white
   Lambertian plane lit from the normal reads 1).
5. **Inter-reflection.** Light bounced by neighbouring relief keeps shadows from being black:
   an indirect term ∝ albedo · cos θ_i · (a small stray-light floor + albedo · occluded
   fraction of the sky), i.e. brighter in cavities of bright materials.

Highlights beyond 1 are compressed smoothly towards 1.5 (a soft knee), which keeps every value
in roughly [0, 1.5] like the tone range of a measured, exposure-fused BTF.

The *true-black* variant (``black=True``) is what a path tracer without inter-reflection or a
measured BTF with deep shadows gives: no inter-reflection term, hard shadows
(:data:`BLACK_PENUMBRA`) and no highlight compression, so shadowed values are exact zeros and
glossy highlights reach tens of times a white diffuse surface.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .sampling import bilinear_wrap
from .surface import SurfaceMaps

__all__ = [
    "BLACK_PENUMBRA",
    "KNEE",
    "MAX_VALUE",
    "LightTable",
    "ambient_occlusion",
    "horizon_slope",
    "parallax_lookup",
    "prepare_lights",
    "shade_view",
    "soft_limit",
]

KNEE = 1.0
#: Shadow-edge half width (radians) of the true-black variant: a point light, hard shadows.
BLACK_PENUMBRA = 0.005
MAX_VALUE = 1.5
_RETRO_WIDTH = 1.0 - np.cos(np.radians(12.0))
_FIBRE_EXPONENT = 24.0
_F32 = np.float32


def soft_limit(x: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """Identity up to :data:`KNEE`, then a tanh shoulder that never exceeds :data:`MAX_VALUE`."""
    res = np.array(x, copy=True) if out is None else out
    if res is not x:
        res[...] = x
    over = res > KNEE
    if np.any(over):
        span = MAX_VALUE - KNEE
        res[over] = KNEE + span * np.tanh((res[over] - KNEE) / span)
    return res


def _march_offsets(height: np.ndarray, slope: float, step: float = 0.5) -> np.ndarray:
    """Distances (texels) at which a shadow ray rising at ``slope`` may still hit relief.

    Steps are ``step`` texels near the start and grow by 6 % of the distance beyond: a far
    occluder subtends a small angle, so coarser sampling there changes the horizon little.
    """
    relief = float(height.max() - height.min())
    reach = min(relief / max(slope, 1e-3), 2.0 * max(height.shape))
    out = []
    t = step
    while t <= reach + step:
        out.append(t)
        t += max(step, 0.06 * t)
    return np.asarray(out if out else [step])


def horizon_slope(height: np.ndarray, azimuth: float, reach_slope: float) -> np.ndarray:
    """Per-texel tangent of the horizon elevation looking along ``azimuth`` (radians from +x).

    Marches up to the distance where a ray rising at ``reach_slope`` (the shallowest light of
    this azimuth) leaves the relief; farther relief cannot shadow any of those lights.
    """
    h, w = height.shape
    rr, cc = np.mgrid[0:h, 0:w]
    drow, dcol = -np.sin(azimuth), np.cos(azimuth)
    best = np.full(height.shape, -np.inf, dtype=_F32)
    for t in _march_offsets(height, reach_slope):
        ahead = bilinear_wrap(height, rr + t * drow, cc + t * dcol)
        np.maximum(best, (ahead - height) / _F32(t), out=best)
    return best


def ambient_occlusion(height: np.ndarray, n_azimuths: int = 8) -> np.ndarray:
    """Cosine-weighted fraction of the sky seen by each texel, from horizons in a few azimuths.

    With horizon elevation α per azimuth, the visible cosine-weighted solid angle is cos²α.
    """
    acc = np.zeros(height.shape, dtype=np.float64)
    for k in range(n_azimuths):
        s = np.maximum(horizon_slope(height, 2 * np.pi * k / n_azimuths, 0.25), 0.0)
        acc += 1.0 / (1.0 + s.astype(np.float64) ** 2)  # cos²(atan s)
    return (acc / n_azimuths).astype(_F32)


@dataclass(frozen=True, eq=False)
class LightTable:
    """Per-light quantities that do not depend on the view: directions and shadow maps."""

    xyz: np.ndarray  # (L, 3) float32
    visibility: np.ndarray  # (H, W, L) float32 in [0, 1], 1 = fully lit


def prepare_lights(
    maps: SurfaceMaps, lights_xyz: np.ndarray, penumbra: float | None = None
) -> LightTable:
    """Soft self-shadowing maps for every light; lights sharing an azimuth share a horizon.

    ``penumbra`` overrides the maps' shadow-edge half width (radians; small = hard shadows).
    """
    penumbra = maps.penumbra if penumbra is None else float(penumbra)
    xyz = np.asarray(lights_xyz, dtype=np.float64)
    height = maps.height
    n = xyz.shape[0]
    vis = np.ones((*height.shape, n), dtype=_F32)
    planar = np.hypot(xyz[:, 0], xyz[:, 1])
    elev = np.arctan2(xyz[:, 2], planar)
    tilted = planar > 1e-9  # a light straight above casts no shadow on a height field
    if np.any(tilted) and float(height.max() - height.min()) > 1e-6:
        az = np.round(np.arctan2(xyz[:, 1], xyz[:, 0]), 9)
        for a in np.unique(az[tilted]):
            group = np.flatnonzero(tilted & (az == a))
            horizon = np.arctan(horizon_slope(height, float(a), float(np.tan(elev[group].min()))))
            for li in group:
                ramp = np.clip(0.5 + (elev[li] - horizon) / (2 * penumbra), 0, 1)
                vis[:, :, li] = ramp * ramp * (3 - 2 * ramp)
    return LightTable(xyz=xyz.astype(_F32), visibility=vis)


def parallax_lookup(height: np.ndarray, view: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Fractional (row, col) of the surface point seen through every reference-plane texel.

    Marches the camera ray from the top of the relief downwards and takes the first crossing
    below the height field, refined linearly between the two bracketing steps.
    """
    h, w = height.shape
    rr, cc = np.mgrid[0:h, 0:w].astype(np.float64)
    v = np.asarray(view, dtype=np.float64)
    planar = float(np.hypot(v[0], v[1]))
    if planar < 1e-9 or v[2] <= 0:
        return rr, cc
    tan_t = planar / max(float(v[2]), 1e-3)
    # Image rows run against +y; one unit of height moves the hit by tan θ along the azimuth.
    drow, dcol = -v[1] / planar * tan_t, v[0] / planar * tan_t
    top, bottom = float(height.max()), float(height.min())
    relief = top - bottom
    if relief < 1e-6:
        return rr + top * drow, cc + top * dcol
    # Half-texel steps along the ray, but at most 96: tall relief on big tiles is smooth.
    n = min(96, max(8, int(np.ceil(relief * tan_t / 0.5)))) + 1
    levels = np.linspace(top, bottom, n)
    prev_t = np.full(rr.shape, top)
    prev_f = np.full(rr.shape, -np.inf)
    hit_t = np.full(rr.shape, bottom)
    found = np.zeros(rr.shape, dtype=bool)
    for t in levels:
        f = bilinear_wrap(height, rr + t * drow, cc + t * dcol).astype(np.float64) - t
        new = (~found) & (f >= 0)
        if np.any(new):
            # Linear refinement between the last step above and the first one below.
            denom = prev_f - f
            with np.errstate(invalid="ignore"):  # −inf / −inf on the first step: masked below
                frac = np.where(
                    np.isfinite(denom) & (denom < 0), prev_f / np.minimum(denom, -1e-12), 0
                )
            frac = np.clip(np.nan_to_num(frac, nan=0.0, posinf=0.0, neginf=0.0), 0, 1)
            hit_t = np.where(new, prev_t + (t - prev_t) * frac, hit_t)
            found |= new
        if found.all():
            break
        prev_t = np.full(rr.shape, t)
        prev_f = f
    return rr + hit_t * drow, cc + hit_t * dcol


def _packed(maps: SurfaceMaps, table: LightTable, ao: np.ndarray) -> np.ndarray:
    """All per-texel quantities in one (H, W, C) array, so a view needs one bilinear gather."""
    ca, sa = np.cos(maps.fibre_angle), np.sin(maps.fibre_angle)
    parts = [
        maps.normal,
        maps.albedo,
        maps.specular,
        maps.roughness[..., None],
        maps.sheen[..., None],
        ca[..., None],
        sa[..., None],
        ao[..., None],
        table.visibility,
    ]
    return np.ascontiguousarray(np.concatenate(parts, axis=-1), dtype=_F32)


def _dot3(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(N, 3) · (L, 3) → (N, L) with explicit products, so results never depend on BLAS."""
    return a[:, 0:1] * b[None, :, 0] + a[:, 1:2] * b[None, :, 1] + a[:, 2:3] * b[None, :, 2]


_CHUNK = 8192  # texels shaded together: bounds memory to a few (chunk, L) arrays


def shade_view(
    maps: SurfaceMaps,
    table: LightTable,
    packed: np.ndarray,
    view: np.ndarray,
    black: bool = False,
) -> np.ndarray:
    """BTF values of all texels and all lights of ``table`` for one view: (H, W, L, 3) float32.

    ``packed`` is :func:`pack`'s array for (``maps``, ``table``). Texels are shaded in chunks
    (vectorised within each) so memory stays small even for 400×400 tiles. ``black`` drops
    the inter-reflection term (shadows are exact zeros) and the highlight compression (values
    are high dynamic range), as a path tracer's or a measured BTF's are.
    """
    hgt, wid = maps.shape
    n_l = table.xyz.shape[0]
    v = np.asarray(view, dtype=np.float64)
    v = (v / np.linalg.norm(v)).astype(_F32)
    rows, cols = parallax_lookup(maps.height, v)
    rows, cols = rows.ravel(), cols.ravel()
    out = np.empty((hgt * wid, n_l, 3), dtype=_F32)
    for start in range(0, hgt * wid, _CHUNK):
        part = slice(start, start + _CHUNK)
        sampled = bilinear_wrap(packed, rows[part], cols[part])  # (n, C)
        out[part] = _shade_points(sampled, v, table.xyz, maps.sheen_model, black)
    if maps.mask is not None:
        # Nearest texel of the seen surface point: a hole stays exactly black.
        r = np.round(rows).astype(np.int64) % hgt
        seen = maps.mask[r, np.round(cols).astype(np.int64) % wid]
        out *= seen[:, None, None]
    return out.reshape(hgt, wid, n_l, 3)


def _shade_points(
    s: np.ndarray, v: np.ndarray, lights: np.ndarray, sheen_model: str, black: bool = False
) -> np.ndarray:
    """Shade sampled surface points ``s`` (n, C packed channels) for all lights: (n, L, 3)."""
    n_l = lights.shape[0]
    n = s[:, 0:3]
    n = n / np.linalg.norm(n, axis=1, keepdims=True)
    albedo, f0 = s[:, 3:6], s[:, 6:9]
    alpha = np.maximum(s[:, 9:10], _F32(0.03))
    sheen = s[:, 10:11]
    ao = s[:, 13:14]
    shadow = s[:, 14 : 14 + n_l]

    half = lights + v[None, :]
    hlen = np.linalg.norm(half, axis=1, keepdims=True)
    # Light and view exactly opposite on the horizon: any half vector will do; use the normal.
    half = np.where(hlen > 1e-6, half / np.maximum(hlen, _F32(1e-6)), _F32([0, 0, 1]))
    nl = _dot3(n, lights)
    nl_pos = np.maximum(nl, 0)
    nv = np.maximum(_dot3(n, v[None, :]), _F32(0.02))
    nh = np.clip(_dot3(n, half), 0, 1)
    lh = np.clip(_dot3(half, v[None, :])[:, 0], 0, 1)
    lit = shadow * nl_pos

    # GGX normal distribution and the separable Smith–Schlick masking-shadowing term.
    a2 = alpha * alpha
    d = nh * nh * (a2 - 1) + 1
    ggx = a2 / (_F32(np.pi) * d * d)
    k = alpha * _F32(0.5)
    g = (nl_pos / (nl_pos * (1 - k) + k)) * (nv / (nv * (1 - k) + k))
    # π·f_r·cos θ_i with f_r = D·G·F / (4 cos θ_i cos θ_o): the cos θ_i cancels.
    spec = ggx
    spec *= g
    spec *= shadow
    spec *= _F32(np.pi / 4) / nv
    # Schlick: F = F0 + (1 − F0)·w, w = (1 − l·h)⁵, split so the per-channel part is F0·(1 − w).
    fresnel_w = ((1 - lh) ** 5)[None, :]
    spec_white = spec * fresnel_w
    spec -= spec_white

    sheen_val = None
    if sheen_model == "fibre":
        t = np.concatenate([s[:, 11:13], np.zeros((s.shape[0], 1), _F32)], axis=1)
        t -= n * np.sum(t * n, axis=1, keepdims=True)
        t /= np.maximum(np.linalg.norm(t, axis=1, keepdims=True), _F32(1e-6))
        th = _dot3(t, half)
        # Kajiya–Kay: fibres reflect into a cone around the fibre axis, peaking where the
        # half vector is perpendicular to the fibre; sheen colour is a lightened dye colour.
        lobe = np.maximum(1 - th * th, 0) ** _F32(_FIBRE_EXPONENT / 2)
        sheen_val = sheen * lobe * np.sqrt(nl_pos) * shadow
        tint = np.sqrt(albedo) * _F32(0.7) + _F32(0.15)
    elif sheen_model == "velvet":
        inv = 1 / np.maximum(alpha, _F32(0.3))
        sin2 = np.maximum(1 - nh * nh, _F32(1e-6))
        charlie = (2 + inv) * sin2 ** (inv * _F32(0.5)) / _F32(2 * np.pi)
        vis_n = 1 / (4 * (nl_pos + nv - nl_pos * nv) + _F32(1e-3))
        grazing = _F32(np.pi) * charlie * vis_n * nl_pos
        # Opposition effect: a fibre pile hides its own shadows when lit from the viewer.
        cos_lv = _dot3(v[None, :], lights)
        retro = np.exp(-(1 - cos_lv) / _F32(_RETRO_WIDTH)) * nl_pos
        sheen_val = (grazing + _F32(0.6) * retro) * shadow * sheen
        tint = np.sqrt(albedo) * _F32(0.8) + _F32(0.1)

    luma = _dot3(albedo, np.array([[0.2126, 0.7152, 0.0722]], dtype=_F32))
    bounce = (_F32(0.07) + _F32(0.6) * luma * (1 - ao)) * np.maximum(lights[:, 2], 0)
    diffuse = lit
    if not black:
        diffuse += bounce

    # Assemble channel by channel from (N, L) terms: far fewer full-size temporaries.
    out = np.empty((s.shape[0], n_l, 3), dtype=_F32)
    chan = np.empty_like(diffuse)
    for c in range(3):
        np.multiply(diffuse, albedo[:, c : c + 1], out=chan)
        chan += spec * f0[:, c : c + 1]
        chan += spec_white
        if sheen_val is not None:
            chan += sheen_val * tint[:, c : c + 1]
        np.maximum(chan, 0, out=chan)
        out[:, :, c] = chan
    return out if black else soft_limit(out, out=out)


def pack(maps: SurfaceMaps, table: LightTable) -> np.ndarray:
    """The packed per-texel array :func:`shade_view` reads (maps, AO and shadow maps)."""
    return _packed(maps, table, ambient_occlusion(maps.height))

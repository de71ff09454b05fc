"""Rendering one view of a capture: every texel and every light in one wavefront pass.

For a view ω_o, ``spp`` camera rays per texel (jittered over the texel's square, rectified
orthographic: :mod:`.geometry`) are traced once; at every path vertex the light's
contribution is added for **all** lights of the set, each a distant directional light of unit
irradiance (on a plane facing it) from ω_l: the vertex's BSDF value f·cos θ_l (Mitsuba's
``eval``) times the throughput, if a shadow ray towards ω_l leaves the sample. The path then
continues by BSDF sampling (one path shared by all lights: next-event estimation to each
light), up to ``max_depth`` segments as Mitsuba's path tracer counts them (2: direct light
only; 3: one bounce of inter-reflection). The lights are shaded in wide passes (vertices ×
lights as one wavefront, up to :data:`MAX_LANES` lanes) and every view-dependent scalar is a
Dr.Jit variable, so all views and lights reuse the same compiled kernels. Nothing else emits:
light that bounces off the sample into the sky is lost, so a cavity that sees no lit surface
is exactly black.

The value stored is π · (mean radiance over the texel) for unit irradiance, i.e. π·f_r·cos θ_l
for a flat sample: a Lambertian plane of albedo ρ gives ρ·cos θ_l in every view, the
convention of our synthetic materials and of UBO2014 (``docs/format.md``).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from .geometry import PERIOD, texel_window

__all__ = ["render_view"]

#: Camera paths traced at once (texels × spp); larger views run in bands of rows.
MAX_LANES = 1 << 20


def _sampler_seed(seed: int, view: int, band: int) -> int:
    """A 32-bit sampler seed per (capture seed, view, band): every view's noise is its own,
    and the same whichever process renders it."""
    h = (seed * 0x9E3779B1 + view * 0x85EBCA77 + band * 0xC2B2AE3D + 0x27D4EB2F) & 0xFFFFFFFF
    return int(h)


def render_view(
    scene: Any,
    z_top: float,
    size: int,
    rows: slice,
    cols: slice,
    view: np.ndarray,
    lights: np.ndarray,
    *,
    spp: int,
    max_depth: int,
    seed: int,
    view_index: int,
) -> np.ndarray:
    """BTF values of the texels ``rows`` × ``cols`` of an N×N capture for view ``view`` (3,)
    and every light of ``lights`` (L, 3): (h, w, L, 3) float32.

    ``scene`` is the tiled Mitsuba scene (:func:`.scene.tiled_scene`), ``z_top`` a height
    above all its relief. Rows are rendered in bands of at most :data:`MAX_LANES` paths.
    """
    x0, y0 = texel_window(size, rows, cols)
    h, w = len(y0), len(x0)
    out = np.empty((h, w, lights.shape[0], 3), dtype=np.float32)
    band = max(1, MAX_LANES // max(1, w * spp))
    for b, r0 in enumerate(range(0, h, band)):
        r1 = min(r0 + band, h)
        out[r0:r1] = _render_band(scene, z_top, size, x0, y0[r0:r1], view, lights, spp,
                                  max_depth, _sampler_seed(seed, view_index, b))  # fmt: skip
    return out


def _render_band(
    scene: Any,
    z_top: float,
    size: int,
    x0: np.ndarray,
    y0: np.ndarray,
    view: np.ndarray,
    lights: np.ndarray,
    spp: int,
    max_depth: int,
    sampler_seed: int,
) -> np.ndarray:
    import drjit as dr
    import mitsuba as mi

    h, w = len(y0), len(x0)
    n = h * w * spp
    lane = dr.arange(mi.UInt32, n)
    texel = lane // spp
    sampler = mi.load_dict({"type": "independent"})
    # View-dependent scalars are opaque: as literals they would make every view a new kernel
    # (an LLVM compilation of seconds); as variables all views share the compiled kernels.
    sampler.seed(dr.opaque(mi.UInt32, sampler_seed), n)
    step = PERIOD / size
    jitter = sampler.next_2d()
    x = dr.gather(mi.Float, mi.Float(x0.astype(np.float32)), texel % w) + jitter.x * step
    y = dr.gather(mi.Float, mi.Float(y0.astype(np.float32)), texel // w) - jitter.y * step
    wo = np.asarray(view, dtype=np.float64)
    wo = wo / np.linalg.norm(wo)
    d = mi.Vector3f(*(dr.opaque(mi.Float, float(c)) for c in wo))
    # Start above the relief, then wrap the origin into the central tile (the sample repeats).
    lift = dr.opaque(mi.Float, float(z_top) / max(float(wo[2]), 1e-6))
    ox = x + d.x * lift
    oy = y + d.y * lift
    ox -= PERIOD * dr.round(ox / PERIOD)
    oy -= PERIOD * dr.round(oy / PERIOD)
    ray = mi.Ray3f(mi.Point3f(ox, oy, z_top), -d)

    ctx = mi.BSDFContext()
    si = scene.ray_intersect(ray)
    active = si.is_valid()
    beta = mi.Spectrum(1.0)
    acc = np.zeros((lights.shape[0], 3, h * w), dtype=np.float64)
    n_lights = lights.shape[0]
    per_pass = max(1, min(n_lights, MAX_LANES // n))  # lights shaded together, one wide pass
    light_table = mi.Vector3f(*(mi.Float(lights[:, k].astype(np.float32)) for k in range(3)))
    for depth in range(max_depth - 1):
        bsdf = si.bsdf(ray)
        dr.eval(si, bsdf, beta, active)
        for l0 in range(0, n_lights, per_pass):
            k = min(per_pass, n_lights - l0)
            acc[l0:l0 + k] += _next_event(scene, si, bsdf, beta, active, light_table, l0, k,
                                          n, spp, ctx)  # fmt: skip
        if depth == max_depth - 2:
            break
        bs, weight = bsdf.sample(ctx, si, sampler.next_1d(active), sampler.next_2d(active),
                                 active)  # fmt: skip
        beta *= weight
        active &= (bs.pdf > 0) & (dr.max(beta) > 0)
        ray = si.spawn_ray(si.to_world(bs.wo))
        si = scene.ray_intersect(ray, active)
        active &= si.is_valid()
    values = acc * (math.pi / spp)  # (L, 3, h·w) → (h, w, L, 3)
    return np.ascontiguousarray(values.transpose(2, 0, 1).reshape(h, w, -1, 3), np.float32)


def _next_event(scene: Any, si: Any, bsdf: Any, beta: Any, active: Any, light_table: Any,
                l0: int, k: int, n: int, spp: int, ctx: Any) -> np.ndarray:  # fmt: skip
    """Direct light of lights ``l0 … l0+k−1`` at the path vertices ``si`` (n lanes), as one
    wavefront of k·n lanes (lane j: vertex j mod n, light l0 + j div n): summed over each
    texel's ``spp`` paths, (k, 3, n/spp) float64."""
    import drjit as dr
    import mitsuba as mi

    wide = dr.arange(mi.UInt32, k * n)
    lane = wide % n
    if k > 1:
        si = dr.gather(type(si), si, lane)
        bsdf = dr.gather(type(bsdf), bsdf, lane)
        beta = dr.gather(type(beta), beta, lane)
        active = dr.gather(type(active), active, lane)
    wl = dr.gather(mi.Vector3f, light_table, wide // n + dr.opaque(mi.UInt32, l0))
    local = si.to_local(wl)
    lit = active & (mi.Frame3f.cos_theta(local) > 0) & (dr.dot(si.n, wl) > 0)
    value = beta * bsdf.eval(ctx, si, local, lit)
    lit &= ~scene.ray_test(si.spawn_ray(wl), lit)
    value = dr.select(lit, value, 0.0)
    summed = np.asarray(dr.block_sum(value, spp), dtype=np.float64)  # (3, k·n/spp)
    return summed.reshape(3, k, n // spp).transpose(1, 0, 2)

"""Automatic level of detail: the τ' of each lookup from its path depth and its footprint.

Coefficients are stored by decreasing magnitude, so a lookup at τ' reads a prefix of its
data point's codes; a fractional τ' fades the next coefficient in
(:func:`~sparsebtf.runtime.kernels.prefix_weights`), so the value is continuous in τ' and no
seam appears where τ' changes across an image. The rule, shared by the Mitsuba plugin
(``lod = "auto"``, Dr.Jit), the WebGL2 viewer (GLSL) and :meth:`RuntimeBTF.evaluate
<sparsebtf.runtime.RuntimeBTF.evaluate>` (a per-query ``tau`` array), is::

    near     = clip(1 / ρ², MIN_FRACTION, 1)           where the camera sees the surface
    fraction = near                                    its eval (light sample) lookup
             = min(near, SAMPLED_FRACTION)             its BSDF-sample lookup (path tracer)
             = LATER_FRACTION                          on path vertices after the first
    τ'_c     = max(fraction · τ_c, min(1, τ_c))        per channel c (τ_c the loaded cap)

with ρ the texels per pixel side (the square root of the texels a pixel covers): a pixel that
averages ρ² texels needs fewer coefficients of each. Vertices after the first are blurred by
the BSDF and weighted by the path throughput, and the weight of a BSDF sample at the first
vertex carries what the continued path finds, so a fraction of τ serves them; the lookup of the
light sample at the first vertex, what the camera sees most directly, keeps the most. The
constants were chosen by measurement (``benchmarks/bench_render.py --lod``, docs/rendering.md
"Level of detail"): a time saving ≥ 2× whose bias stays far below the noise of a 16-spp image
on every material measured (1/ρ² floored at 0.1 instead of 0.5 cost a bias twice the noise).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from ..model import CHANNELS

__all__ = [
    "COS_FLOOR",
    "LATER_FRACTION",
    "LODS",
    "MIN_FRACTION",
    "SAMPLED_FRACTION",
    "cone_texels_per_pixel",
    "footprint_fraction",
    "lod_tau",
]

#: The values of the plugin's and the CLI's ``lod``.
LODS = ("auto", "off")
#: Fraction of τ on path vertices after the one the camera sees.
LATER_FRACTION = 0.1
#: Fraction of τ at most for the lookup of a path tracer's BSDF sample at the first vertex:
#: its weight carries what the continued path finds (indirect light, and the BSDF-sampled
#: share of direct light under multiple importance sampling).
SAMPLED_FRACTION = 0.3
#: The least fraction the footprint rule gives (a far-away surface).
MIN_FRACTION = 0.5
#: Grazing views count as this cos θ (the footprint's stretch stays bounded).
COS_FLOOR = 0.05


def cone_texels_per_pixel(
    t: np.ndarray, pixel: float, cos_theta: np.ndarray, du: np.ndarray, dv: np.ndarray,
    texel_area: float,
) -> np.ndarray:
    """ρ of a camera ray (a ray cone): a pixel of ``pixel`` radians at distance ``t`` covers a
    surface patch of side t·pixel/√max(|cos θ|, :data:`COS_FLOOR`) (the square of the same
    area as the ellipse), a texel has side √(|∂p/∂u|·|∂p/∂v|·texel_area) with ``du``, ``dv``
    the lengths of ∂p/∂u, ∂p/∂v and texel_area = 1/(H·W·uv_scale²) in uv units."""
    cos = np.maximum(np.abs(np.asarray(cos_theta, dtype=np.float64)), COS_FLOOR)
    texel = np.sqrt(np.asarray(du, np.float64) * np.asarray(dv, np.float64) * texel_area)
    return np.asarray(t, np.float64) * pixel / np.sqrt(cos) / np.maximum(texel, 1e-12)


def footprint_fraction(texels_per_pixel: np.ndarray | float) -> np.ndarray:
    """clip(1/ρ², :data:`MIN_FRACTION`, 1) for ρ texels per pixel side (ρ ≤ 1: the full τ)."""
    rho = np.maximum(np.asarray(texels_per_pixel, dtype=np.float64), 1.0)
    return np.clip(1.0 / (rho * rho), MIN_FRACTION, 1.0)


def lod_tau(tau: Mapping[str, int] | Sequence[int], fraction: np.ndarray) -> np.ndarray:
    """(n, 3) per-query τ' (Y, U, V) for ``RuntimeBTF.evaluate(tau=...)``: max(f·τ_c, 1),
    never above τ_c; ``tau`` the loaded τ per channel, ``fraction`` (n,) in (0, 1]."""
    t = np.array([tau[ch] for ch in CHANNELS] if isinstance(tau, Mapping) else tau, np.float64)
    f = np.asarray(fraction, dtype=np.float64)[:, None]
    return np.maximum(f * t[None, :], np.minimum(1.0, t)[None, :])

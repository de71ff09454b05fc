"""The virtual gonioreflectometer's geometry: the sample tile, its texels, the rectified
orthographic view and how many copies of the tile a capture needs around it.

Conventions (the tangent frame of :mod:`sparsebtf.data.directions`): the sample lies on the
plane z = 0 with its normal along +z; one period of it fills the **tile** x, y ∈ [−1, 1]
(Mitsuba's ``rectangle``), and the sample repeats with period 2 along x and y. Texel (r, c) of
an N×N capture covers x ∈ −1 + [c, c + 1]·2/N and y ∈ 1 − [r + 1, r]·2/N: columns run along +x,
rows run *down* the image, against +y, as in every BTF here.

**Rectified orthographic view.** For the view direction ω_o (towards the camera), the pixel of
texel (r, c) sees along the ray x(t) = p − t·ω_o through the texel's point p on z = 0. All
views share that texel grid on the reference plane z = 0, so texel (x, y) is the same spot of
the sample in every view (UBO2014's rectified images), and relief above or below the plane
moves by its height·tan θ_o (parallax), as measured. The ray starts above the tallest relief
and its origin is wrapped into the central tile: the sample is periodic, so the wrapped ray
sees what the original one sees.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = [
    "PERIOD",
    "grazing_tan",
    "ring_count",
    "texel_window",
]

#: The sample's period along x and y (the tile is [−1, 1]²).
PERIOD = 2.0
#: Most rings of tile copies around the central one (a (2k+1)² grid); beyond it relief is too
#: tall for the grazing directions asked and far rays see no geometry.
MAX_RINGS = 12
#: tan θ is taken at most at θ = 85° (a direction closer to the horizon needs rings without end).
_MAX_TAN = math.tan(math.radians(85.0))


def grazing_tan(xyz: np.ndarray) -> float:
    """tan θ of the direction of ``xyz`` (n, 3) closest to the horizon, capped at 85°."""
    z = np.clip(np.asarray(xyz, dtype=np.float64)[:, 2], 1e-9, 1.0)
    tan = np.sqrt(np.maximum(1.0 - z * z, 0.0)) / z
    return float(min(float(tan.max()), _MAX_TAN))


def ring_count(z_range: float, overhang: float, tan_view: float, tan_light: float) -> int:
    """Rings k of tile copies around the central tile (a (2k+1)² grid) that a capture needs.

    A camera ray enters the relief slab (height ``z_range``) over the central tile and moves
    sideways at most z_range·tan θ_o before it hits; a shadow ray from there moves at most
    z_range·tan θ_l more before it leaves the slab. Copy i (offset 2i) reaches to
    2i − 1 − ``overhang`` (the shapes' reach beyond the tile), so copies up to
    i = 1 + (D + overhang)/2 with D the sum of both reaches can be met; one more ring serves the
    bounced rays of inter-reflection.
    """
    reach = max(z_range, 0.0) * (tan_view + tan_light)
    return int(min(MAX_RINGS, math.floor(1.0 + (reach + max(overhang, 0.0)) / PERIOD) + 1))


def texel_window(size: int, rows: slice, cols: slice) -> tuple[np.ndarray, np.ndarray]:
    """Left and top edges (x0 (w,), y0 (h,)) of the texels of ``rows`` × ``cols`` of an
    N×N capture; a texel spans [x0, x0 + 2/N] × [y0 − 2/N, y0]."""
    step = PERIOD / size
    c = np.arange(size)[cols]
    r = np.arange(size)[rows]
    return -1.0 + c * step, 1.0 - r * step

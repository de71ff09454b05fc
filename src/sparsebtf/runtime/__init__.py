"""Runtime (paper §3.4–3.5): local evaluation, angular interpolation, level of detail, blending.

* :class:`RuntimeBTF` — Eq. 5/6 for batches of (texel or uv, ω_i, ω_o) queries, τ' truncation,
  and the flat arrays a shader needs (:meth:`RuntimeBTF.arrays`).
* :func:`angular_weights` — nearest / linear (release) / barycentric / Gaussian neighbours.
* :func:`blend` — inter-BTF interpolation in coefficient space (Eq. 7–9).
"""

from __future__ import annotations

from .angular import SCHEMES, angular_weights, neighbour_table
from .blend import blend
from .decoder import RuntimeBTF, texels_from_uv

__all__ = [
    "SCHEMES",
    "RuntimeBTF",
    "angular_weights",
    "blend",
    "neighbour_table",
    "texels_from_uv",
]

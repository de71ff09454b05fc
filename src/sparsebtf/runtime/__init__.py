"""Runtime (paper §3.4–3.5): every read of sparse codes.

* :func:`coded_btf_view`, :func:`decode_points` — a coded BTF decoded lazily as a BTF (Eq. 4,
  and Eq. 5 for a few directions).
* :class:`RuntimeBTF` — Eq. 5/6 for batches of (texel or uv, ω_i, ω_o) queries, τ' truncation,
  and the flat arrays a shader needs (:meth:`RuntimeBTF.arrays`).
* :class:`AdaptiveRuntimeBTF`, :class:`AdaptiveDecodedBTF` — the same for a material coded
  with adaptive patch sizes (NumPy or numba, layer by layer; :mod:`.adaptive`).
* :func:`angular_weights` — nearest / linear (release) / barycentric / Gaussian neighbours.
* :func:`blend` — inter-BTF interpolation in coefficient space (Eq. 7–9).
"""

from __future__ import annotations

from .adaptive import AdaptiveDecodedBTF, AdaptiveRuntimeBTF
from .angular import SCHEMES, DirectionIndex, angular_weights, neighbour_table
from .blend import blend
from .decoder import RuntimeBTF, texels_from_uv
from .dense import DecodedBTF, coded_btf_view, decode_points, decode_points_eq5

__all__ = [
    "SCHEMES",
    "AdaptiveDecodedBTF",
    "AdaptiveRuntimeBTF",
    "DecodedBTF",
    "DirectionIndex",
    "RuntimeBTF",
    "angular_weights",
    "blend",
    "coded_btf_view",
    "decode_points",
    "decode_points_eq5",
    "neighbour_table",
    "texels_from_uv",
]

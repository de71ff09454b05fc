"""The highlight store's correction in the ``sparsebtf`` plugin's Dr.Jit lookup (issue 46).

As :mod:`sparsebtf.runtime.highlight_lookup` (whose NumPy reference is
:func:`sparsebtf.learning.highlights.correction`): the decoded linear RGB plus
Σ_ab wl_a · wv_b · c(x, l_a, v_b) over the lookup's own angular neighbours, clamped at 0, with
c found by a binary search of the node's key in its point's range of the sorted keys.
``dr.binary_search`` takes scalar bounds only (one range for every lane), so the search here
is written out with per-lane bounds and a fixed number of steps: enough for the largest
point's range. Like :mod:`.kernels`, it takes ``mi`` and ``dr`` as arguments.
"""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["HighlightArrays", "add_highlights"]


class HighlightArrays:
    """A highlight store as Dr.Jit arrays of the active variant: ``offsets`` (P + 1) and
    ``keys`` (N) UInt32, ``rgb`` (3N) Float interleaved, ``steps`` the binary search's steps
    (bits of the largest per-point count) and the key's strides."""

    def __init__(self, mi: Any, arrays: dict[str, np.ndarray], patch: int, n_lights: int,
                 n_views: int) -> None:  # fmt: skip
        offsets = arrays["highlight_offsets"]
        self.steps = int(np.diff(offsets.astype(np.int64)).max(initial=0)).bit_length()
        self.offsets = mi.UInt32(offsets)
        self.keys = mi.UInt32(arrays["highlight_keys"])
        self.rgb = mi.Float(arrays["highlight_rgb"].ravel())
        self.patch, self.n_lights, self.n_views = int(patch), int(n_lights), int(n_views)

    @classmethod
    def of(cls, mi: Any, arrays: dict[str, np.ndarray], patch: int, n_lights: int,
           n_views: int) -> HighlightArrays | None:  # fmt: skip
        """The store among the renderer arrays ``arrays`` (``RuntimeBTF.arrays()``: uint32
        offsets and keys, float32 RGB), or None where they have none (no store, no entries,
        an adaptive material): the lookup is then traced exactly as without."""
        if "highlight_keys" not in arrays:
            return None
        return cls(mi, arrays, patch, n_lights, n_views)


def _lower_bound(mi: Any, dr: Any, hl: HighlightArrays, lo: Any, hi: Any, key: Any,
                 active: Any) -> Any:
    """First index in [lo, hi) whose key is >= ``key`` (hi if none), per lane."""
    for _ in range(hl.steps):
        open_ = lo < hi
        mid = (lo + hi) >> 1
        less = open_ & (dr.gather(mi.UInt32, hl.keys, mid, active & open_) < key)
        lo = dr.select(less, mid + 1, lo)
        hi = dr.select(open_ & ~less, mid, hi)
    return lo


def correction(mi: Any, dr: Any, hl: HighlightArrays, pt: Any, i1: Any, i2: Any,
               light_nb: tuple[list, list], view_nb: tuple[list, list], active: Any) -> Any:
    """Σ_ab wl_a · wv_b · c(point, key(i1, i2, l_a, v_b)) per lane: Color3f (0 where no node
    of the lane's neighbour pairs has an entry)."""
    li, lw = light_nb
    vi, vw = view_nb
    s0 = dr.gather(mi.UInt32, hl.offsets, pt, active)
    s1 = dr.select(active, dr.gather(mi.UInt32, hl.offsets, pt + 1, active), s0)
    texel = i1 * hl.patch + i2
    out = mi.Color3f(0.0)
    for a in range(len(lw)):
        base = (texel * hl.n_lights + li[a]) * hl.n_views
        for b in range(len(vw)):
            key = base + vi[b]
            j = _lower_bound(mi, dr, hl, mi.UInt32(s0), mi.UInt32(s1), key, active)
            hit = active & (j < s1)
            hit &= dr.gather(mi.UInt32, hl.keys, j, hit) == key
            c = dr.gather(mi.Color3f, hl.rgb, j, hit)  # 0 where masked off
            out += (lw[a] * vw[b]) * c
    return out


def add_highlights(mi: Any, dr: Any, hl: HighlightArrays | None, rgb: Any, pt: Any, i1: Any,
                   i2: Any, light_nb: tuple[list, list], view_nb: tuple[list, list],
                   active: Any) -> Any:
    """max(``rgb`` + :func:`correction`, 0); ``rgb`` itself (no clamp) without a store."""
    if hl is None:
        return rgb
    return dr.maximum(rgb + correction(mi, dr, hl, pt, i1, i2, light_nb, view_nb, active), 0.0)

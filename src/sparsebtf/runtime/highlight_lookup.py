"""The highlight store's correction added to decoded values (issue 46), compiled.

Every decoder returns ``max(decode + Σ_ab wl_a · wv_b · c(x, l_a, v_b), 0)`` with the angular
neighbours and weights of its own Eq. 6 interpolation and c = 0 at a node without an entry
(:mod:`sparsebtf.learning.highlights`, whose :func:`~sparsebtf.learning.highlights.correction`
is the NumPy reference and the fallback without numba). Per query and neighbour pair the
kernel binary-searches the node's key in its point's range ``offsets[p] : offsets[p + 1]`` of
the sorted keys.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._numba import HAVE_NUMBA
from .._numba import numba as _nb
from ..learning.highlights import Highlights, correction

__all__ = ["HighlightTable", "add_highlights"]


@dataclass(frozen=True)
class HighlightTable:
    """A store in the decoders' types, converted once per runtime.

    Attributes
    ----------
    store : the :class:`~sparsebtf.learning.highlights.Highlights` (the reference's input).
    offsets : (P + 1,) int64; keys : (N,) uint32; rgb : (N, 3) float32 (binary16 widened).
    patch, n_lights, n_views : the key's strides (:func:`~sparsebtf.learning.highlights.
        node_keys`).
    """

    store: Highlights
    offsets: np.ndarray
    keys: np.ndarray
    rgb: np.ndarray
    patch: int
    n_lights: int
    n_views: int

    @classmethod
    def of(cls, h: Highlights | None, patch: int, n_lights: int, n_views: int
           ) -> HighlightTable | None:  # fmt: skip
        """The table of ``h``, or None without a store or without entries (then the decoders
        run exactly as without highlights)."""
        if h is None or not h.n_entries:
            return None
        return cls(h, np.ascontiguousarray(h.offsets, dtype=np.int64),
                   np.ascontiguousarray(h.keys, dtype=np.uint32),
                   np.ascontiguousarray(h.rgb, dtype=np.float32), int(patch), int(n_lights),
                   int(n_views))  # fmt: skip


if HAVE_NUMBA:

    @_nb.njit(cache=True, nogil=True, inline="always")
    def _find(keys, lo, hi, key):
        # index of ``key`` in the sorted keys[lo:hi], or -1 (lower bound, then a test)
        end = hi
        while lo < hi:
            mid = (lo + hi) >> 1
            if np.int64(keys[mid]) < key:
                lo = mid + 1
            else:
                hi = mid
        if lo < end and np.int64(keys[lo]) == key:
            return lo
        return -1

    @_nb.njit(parallel=True, cache=True, nogil=True)
    def _add_nb(out, pts, i1, i2, li, lw, vi, vw, offsets, keys, rgb, patch, n_lights,
                n_views, order):  # fmt: skip
        # row q of the query inputs answers output row order[q] (none given: q); the
        # correction is summed in float64, added, clamped at 0 and stored in out's type
        n = pts.shape[0]
        ordered = order.shape[0] > 0
        kl = li.shape[1]
        kv = vi.shape[1]
        for q in _nb.prange(n):
            p = pts[q]
            lo, hi = offsets[p], offsets[p + 1]  # empty for a point without entries
            texel = np.int64(i1[q]) * patch + np.int64(i2[q])
            c0 = c1 = c2 = 0.0
            for a in range(kl):
                base = (texel * n_lights + np.int64(li[q, a])) * n_views
                for b in range(kv):
                    j = _find(keys, lo, hi, base + np.int64(vi[q, b]))
                    if j >= 0:
                        w = np.float64(lw[q, a]) * np.float64(vw[q, b])
                        c0 += w * rgb[j, 0]
                        c1 += w * rgb[j, 1]
                        c2 += w * rgb[j, 2]
            r = order[q] if ordered else np.int64(q)
            v0 = out[r, 0] + c0
            v1 = out[r, 1] + c1
            v2 = out[r, 2] + c2
            out[r, 0] = 0.0 if v0 < 0.0 else v0  # NaN stays NaN (as np.maximum)
            out[r, 1] = 0.0 if v1 < 0.0 else v1
            out[r, 2] = 0.0 if v2 < 0.0 else v2


def _add_numpy(out: np.ndarray, t: HighlightTable, pts: np.ndarray, i1: np.ndarray,
               i2: np.ndarray, li: np.ndarray, lw: np.ndarray, vi: np.ndarray, vw: np.ndarray,
               order: np.ndarray | None) -> None:  # fmt: skip
    c = correction(t.store, pts, i1, i2, li, lw, vi, vw, t.patch, t.n_lights, t.n_views)
    rows = slice(None) if order is None else order
    out[rows] = np.maximum(out[rows] + c, 0.0)


def add_highlights(out: np.ndarray, t: HighlightTable | None, pts: np.ndarray, i1: np.ndarray,
                   i2: np.ndarray, li: np.ndarray, lw: np.ndarray, vi: np.ndarray,
                   vw: np.ndarray, order: np.ndarray | None = None, backend: str = "numba"
                   ) -> np.ndarray:  # fmt: skip
    """``out`` (n, 3) linear RGB (float32 or float64, in place) ← max(out + correction, 0).

    ``pts``, ``i1``, ``i2`` (n,): each query's point and texel in it; ``li``/``lw`` (n, kl) and
    ``vi``/``vw`` (n, kv): its angular neighbours and weights (those of the decode). ``order``
    (n,) a permutation: query row q answers output row ``order[q]`` (the compiled decoder's
    group order). Without a table (None) ``out`` is returned untouched: no clamp either.
    ``backend`` "numba" (when installed) or "numpy" (the reference
    :func:`~sparsebtf.learning.highlights.correction`).
    """
    if t is None or not pts.size:
        return out
    if backend != "numba" or not HAVE_NUMBA:
        _add_numpy(out, t, pts, i1, i2, li, lw, vi, vw, order)
        return out
    o = np.empty(0, dtype=np.int64) if order is None else np.ascontiguousarray(order, np.int64)
    _add_nb(out, np.ascontiguousarray(pts), np.ascontiguousarray(i1), np.ascontiguousarray(i2),
            np.ascontiguousarray(li), np.ascontiguousarray(lw), np.ascontiguousarray(vi),
            np.ascontiguousarray(vw), t.offsets, t.keys, t.rgb, t.patch, t.n_lights,
            t.n_views, o)  # fmt: skip
    return out

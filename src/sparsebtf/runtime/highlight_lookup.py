"""The highlight store's correction added to decoded values (issue 46), compiled.

Every decoder returns ``max(decode + Σ_ab wl_a · wv_b · c(x, l_a, v_b) + lobe(x, ω_i, ω_o), 0)``
with the angular neighbours and weights of its own Eq. 6 interpolation, c = 0 at a node without
an entry, and the texel's highlight lobe (if the store has lobes) evaluated analytically at the
query's own directions — not interpolated from nodes, so a lobe narrower than the direction
sampling keeps its peak (:mod:`sparsebtf.learning.highlights`, whose
:func:`~sparsebtf.learning.highlights.correction` and
:func:`~sparsebtf.learning.highlights.lobe_corrections` are the NumPy reference and the
fallback without numba). Per query and neighbour pair the kernel binary-searches the node's key
in its point's range ``offsets[p] : offsets[p + 1]`` of the sorted keys.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._numba import HAVE_NUMBA
from .._numba import numba as _nb
from ..learning.highlights import Highlights, correction, lobe_corrections
from ..learning.lobes import NV_FLOOR

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
    lobes : (P, p², 8) float32, the store's lobes (binary16 widened), or (0, 0, 8) without.
    """

    store: Highlights
    offsets: np.ndarray
    keys: np.ndarray
    rgb: np.ndarray
    patch: int
    n_lights: int
    n_views: int
    lobes: np.ndarray

    @property
    def has_lobes(self) -> bool:
        return self.lobes.shape[0] > 0

    @classmethod
    def of(cls, h: Highlights | None, patch: int, n_lights: int, n_views: int
           ) -> HighlightTable | None:  # fmt: skip
        """The table of ``h``, or None without a store or with an empty one (no entries and no
        lobes: then the decoders run exactly as without highlights)."""
        if h is None or h.empty_store:
            return None
        lobes = (np.zeros((0, 0, 8), dtype=np.float32) if h.lobes is None
                 else np.ascontiguousarray(h.lobes, dtype=np.float32))  # fmt: skip
        return cls(h, np.ascontiguousarray(h.offsets, dtype=np.int64),
                   np.ascontiguousarray(h.keys, dtype=np.uint32),
                   np.ascontiguousarray(h.rgb, dtype=np.float32), int(patch), int(n_lights),
                   int(n_views), lobes)  # fmt: skip


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

    @_nb.njit(cache=True, nogil=True, inline="always")
    def _lobe(prm, ix, iy, iz, ox, oy, oz):
        # learning.lobes.lobe_values of one texel's parameters prm (8,) at directions ω_i, ω_o
        # (normalised here), float64; the frame's columns written out from
        # R = I + a·K + b·K² with K² = ω ωᵀ − θ² I (lobe_frame's series below θ² = 1e-8)
        wx, wy, wz = np.float64(prm[0]), np.float64(prm[1]), np.float64(prm[2])
        th2 = wx * wx + wy * wy + wz * wz
        if th2 < 1e-8:
            a = 1.0 - th2 / 6.0
            b = 0.5 - th2 / 24.0
        else:
            th = np.sqrt(th2)
            a = np.sin(th) / th
            b = (1.0 - np.cos(th)) / th2
        d = 1.0 - b * th2
        tx, ty, tz = d + b * wx * wx, a * wz + b * wy * wx, -a * wy + b * wz * wx
        bx, by, bz = -a * wz + b * wx * wy, d + b * wy * wy, a * wx + b * wz * wy
        nx, ny, nz = a * wy + b * wx * wz, -a * wx + b * wy * wz, d + b * wz * wz
        li_ = max(np.sqrt(ix * ix + iy * iy + iz * iz), 1e-300)
        lo_ = max(np.sqrt(ox * ox + oy * oy + oz * oz), 1e-300)
        ix, iy, iz = ix / li_, iy / li_, iz / li_
        ox, oy, oz = ox / lo_, oy / lo_, oz / lo_
        nl = ix * nx + iy * ny + iz * nz
        nv = ox * nx + oy * ny + oz * nz
        if not (nl > 0.0 and nv > 0.0):
            return 0.0, 0.0, 0.0
        hx, hy, hz = ix + ox, iy + oy, iz + oz
        hl = max(np.sqrt(hx * hx + hy * hy + hz * hz), 1e-12)
        hx, hy, hz = hx / hl, hy / hl, hz / hl
        ax, ay = np.exp(np.float64(prm[3])), np.exp(np.float64(prm[4]))
        ht = (hx * tx + hy * ty + hz * tz) / ax
        hb = (hx * bx + hy * by + hz * bz) / ay
        hn = hx * nx + hy * ny + hz * nz
        q = ht * ht + hb * hb + hn * hn
        g = 1.0 / (np.pi * ax * ay * q * q) / max(nv, NV_FLOOR)
        return g * np.float64(prm[5]), g * np.float64(prm[6]), g * np.float64(prm[7])

    @_nb.njit(parallel=True, cache=True, nogil=True)
    def _add_nb(out, pts, i1, i2, li, lw, vi, vw, offsets, keys, rgb, patch, n_lights,
                n_views, order, lobes, wi, wo):  # fmt: skip
        # row q of the query inputs answers output row order[q] (none given: q), whose
        # directions are wi/wo[order[q]] (they stay in the caller's query order); the
        # correction and the lobe are summed in float64, added, clamped at 0 and stored in
        # out's type
        n = pts.shape[0]
        ordered = order.shape[0] > 0
        with_lobes = lobes.shape[0] > 0
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
            if with_lobes:
                e0, e1, e2 = _lobe(lobes[p, texel], np.float64(wi[r, 0]), np.float64(wi[r, 1]),
                                   np.float64(wi[r, 2]), np.float64(wo[r, 0]),
                                   np.float64(wo[r, 1]), np.float64(wo[r, 2]))  # fmt: skip
                c0 += e0
                c1 += e1
                c2 += e2
            v0 = out[r, 0] + c0
            v1 = out[r, 1] + c1
            v2 = out[r, 2] + c2
            out[r, 0] = 0.0 if v0 < 0.0 else v0  # NaN stays NaN (as np.maximum)
            out[r, 1] = 0.0 if v1 < 0.0 else v1
            out[r, 2] = 0.0 if v2 < 0.0 else v2


def _add_numpy(out: np.ndarray, t: HighlightTable, pts: np.ndarray, i1: np.ndarray,
               i2: np.ndarray, li: np.ndarray, lw: np.ndarray, vi: np.ndarray, vw: np.ndarray,
               wi: np.ndarray, wo: np.ndarray, order: np.ndarray | None) -> None:  # fmt: skip
    c = correction(t.store, pts, i1, i2, li, lw, vi, vw, t.patch, t.n_lights, t.n_views)
    rows = slice(None) if order is None else order
    if t.has_lobes:
        texels = np.asarray(i1, dtype=np.int64) * t.patch + np.asarray(i2, dtype=np.int64)
        c += lobe_corrections(t.store, pts, texels, np.asarray(wi)[rows], np.asarray(wo)[rows])
    out[rows] = np.maximum(out[rows] + c, 0.0)


def add_highlights(out: np.ndarray, t: HighlightTable | None, pts: np.ndarray, i1: np.ndarray,
                   i2: np.ndarray, li: np.ndarray, lw: np.ndarray, vi: np.ndarray,
                   vw: np.ndarray, wi: np.ndarray, wo: np.ndarray,
                   order: np.ndarray | None = None, backend: str = "numba"
                   ) -> np.ndarray:  # fmt: skip
    """``out`` (n, 3) linear RGB (float32 or float64, in place) ← max(out + correction + lobe,
    0).

    ``pts``, ``i1``, ``i2`` (n,): each query's point and texel in it; ``li``/``lw`` (n, kl) and
    ``vi``/``vw`` (n, kv): its angular neighbours and weights (those of the decode); ``wi``,
    ``wo`` (n, 3): its light and view directions (any length; the lobes are evaluated there),
    in the caller's query order, i.e. the output's. ``order`` (n,) a permutation: query input
    row q (``pts`` … ``vw``) answers output row ``order[q]``, whose directions are
    ``wi[order[q]]``, ``wo[order[q]]`` (the compiled decoder's group order). Without a table
    (None) ``out`` is returned untouched: no clamp either. ``backend`` "numba" (when
    installed) or "numpy" (the reference :func:`~sparsebtf.learning.highlights.correction`
    and :func:`~sparsebtf.learning.highlights.lobe_corrections`).
    """
    if t is None or not pts.size:
        return out
    if backend != "numba" or not HAVE_NUMBA:
        _add_numpy(out, t, pts, i1, i2, li, lw, vi, vw, wi, wo, order)
        return out
    o = np.empty(0, dtype=np.int64) if order is None else np.ascontiguousarray(order, np.int64)
    if t.has_lobes:
        wi, wo = (np.ascontiguousarray(w, dtype=np.float64) for w in (wi, wo))
    else:  # not read: no conversion of the caller's directions
        wi = wo = np.zeros((0, 3))
    _add_nb(out, np.ascontiguousarray(pts), np.ascontiguousarray(i1), np.ascontiguousarray(i2),
            np.ascontiguousarray(li), np.ascontiguousarray(lw), np.ascontiguousarray(vi),
            np.ascontiguousarray(vw), t.offsets, t.keys, t.rgb, t.patch, t.n_lights,
            t.n_views, o, t.lobes, wi, wo)  # fmt: skip
    return out

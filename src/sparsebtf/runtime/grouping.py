"""Queries put in the order the compiled lookup sums them: sorted by data point (by texel where
a texel has many queries) and cut into groups of at most :data:`GROUP`, their inputs gathered
in that order and their answers written back (:mod:`.wavefront` sums the groups)."""

from __future__ import annotations

import itertools

import numpy as np

from .._numba import HAVE_NUMBA
from .._numba import numba as _nb

__all__ = ["GROUP", "TEXEL_GROUPING", "group_by_point", "group_queries", "rows_in_order"]

#: Queries per group: lanes of the vector loops (32 float32 = two AVX-512 or four AVX2
#: registers per table row; the tables of a UBO2014 group fit in L1/L2 even when every mode
#: is whole: (100 + 151 + 151) rows × 32 × 4 bytes = 51 KB).
GROUP = 32

def _group_numpy(pts: np.ndarray, width: int) -> tuple[np.ndarray, np.ndarray]:
    order = np.argsort(pts, kind="stable")
    sp = pts[order]
    cut = np.flatnonzero(sp[1:] != sp[:-1]) + 1
    bounds = np.concatenate(([0], cut, [sp.size]))
    starts = [np.arange(a, b, width) for a, b in itertools.pairwise(bounds)]
    return order, np.concatenate([*starts, [sp.size]]).astype(np.int64)


if HAVE_NUMBA:

    @_nb.njit(cache=True, nogil=True)
    def _group_nb(pts, n_points, width):
        n = pts.shape[0]
        count = np.zeros(n_points + 1, dtype=np.int64)
        for q in range(n):
            count[pts[q] + 1] += 1
        n_groups = 0
        for p in range(n_points):
            n_groups += (count[p + 1] + width - 1) // width
            count[p + 1] += count[p]
        order = np.empty(n, dtype=np.int64)
        fill = count[:n_points].copy()
        for q in range(n):
            p = pts[q]
            order[fill[p]] = q
            fill[p] += 1
        starts = np.empty(n_groups + 1, dtype=np.int64)
        g = 0
        for p in range(n_points):
            for s in range(count[p], count[p + 1], width):
                starts[g] = s
                g += 1
        starts[g] = n
        return order, starts
if HAVE_NUMBA:

    @_nb.njit(parallel=True, cache=True, nogil=True)
    def _take_nb(a, order):
        # out[i] = a[order[i]] (numba types a tuple concatenation, not a starred tuple)
        out = np.empty((order.shape[0],) + a.shape[1:], dtype=a.dtype)  # noqa: RUF005
        for i in _nb.prange(order.shape[0]):
            out[i] = a[order[i]]
        return out

    @_nb.njit(parallel=True, cache=True, nogil=True)
    def _put_nb(a, order):
        # out[order[i]] = a[i]
        out = np.empty_like(a)
        for i in _nb.prange(order.shape[0]):
            out[order[i]] = a[i]
        return out


if HAVE_NUMBA:

    @_nb.njit(parallel=True, cache=True, nogil=True)
    def locate_nb(t, height, width, patch, from_uv):
        # decoder.query_texels and PatchGrid.locate in one pass: (row, col) from uv
        # (wrapping, ⌊frac·size⌋) or from integer texels, then the point (row block fastest)
        # and the texel in its patch; bad[q]: uv not finite or texel outside the texture.
        n = t.shape[0]
        nrb = height // patch
        pts = np.empty(n, dtype=np.int64)
        i1 = np.empty(n, dtype=np.int64)
        i2 = np.empty(n, dtype=np.int64)
        bad = np.zeros(n, dtype=np.bool_)
        n_bad = 0
        for q in _nb.prange(n):
            if from_uv:
                u, v = t[q, 0], t[q, 1]
                if not (np.isfinite(u) and np.isfinite(v)):
                    bad[q] = True
                    n_bad += 1
                    u = v = 0.0
                row = min(np.int64((v - np.floor(v)) * height), height - 1)
                col = min(np.int64((u - np.floor(u)) * width), width - 1)
            else:
                row, col = np.int64(t[q, 0]), np.int64(t[q, 1])
                if row < 0 or row >= height or col < 0 or col >= width:
                    bad[q] = True
                    n_bad += 1
                    row = col = 0
            pts[q] = row // patch + nrb * (col // patch)
            i1[q] = row % patch
            i2[q] = col % patch
        return pts, i1, i2, bad, n_bad


def rows_in_order(a: np.ndarray, order: np.ndarray, back: bool = False) -> np.ndarray:
    """``a[order]`` for 1-D or 2-D ``a`` and an int64 permutation ``order`` (``back``: the
    inverse, ``out[order] = a``): a parallel gather where numba is present (NumPy's fancy
    indexing runs on one thread)."""
    if HAVE_NUMBA and a.ndim in (1, 2):
        return (_put_nb if back else _take_nb)(np.ascontiguousarray(a), order)
    if not back:
        return a[order]
    out = np.empty_like(a)
    out[order] = a
    return out


#: Queries on one texel from which the runtime gives that texel groups of its own: a group on
#: one texel shares its spatial factors, so a coefficient costs one scalar term for the whole
#: group instead of a term per lane, but a texel with few queries leaves its groups part
#: empty. Measured on ``benchmarks/bench_lookup.py``'s captured material, both groupings
#: alternated in one process (every texel with about the same number of queries): texel
#: groups run at 0.30×, 0.50×, 0.63× and 0.88× the rate of point groups at 2, 4, 8 and 12
#: queries per texel, 1.0× at 16, 1.06–1.5× from 20 on.
TEXEL_GROUPING = 16
#: Texel keys per query above which :func:`group_queries` does not count queries per texel
#: (a huge texture under a small batch: its two counting arrays would outweigh the batch).
_TEXEL_KEYS_PER_QUERY = 4


if HAVE_NUMBA:

    @_nb.njit(cache=True, nogil=True)
    def _group_texels_nb(tkey, n_points, per_point, width, threshold):
        # A counting sort by texel key (point·per_point + texel); per point, the texels with
        # >= threshold queries first, each cut into groups of its own, then the point's other
        # queries (in texel order) cut into shared groups of up to ``width``.
        n = tkey.shape[0]
        n_keys = n_points * per_point
        count = np.zeros(n_keys, dtype=np.int64)
        for q in range(n):
            count[tkey[q]] += 1
        pos = np.empty(n_keys, dtype=np.int64)
        starts = np.empty(n + 1, dtype=np.int64)
        g = 0
        cur = 0
        for p in range(n_points):
            k0 = p * per_point
            for t in range(k0, k0 + per_point):
                if count[t] >= threshold:
                    pos[t] = cur
                    for s in range(cur, cur + count[t], width):
                        starts[g] = s
                        g += 1
                    cur += count[t]
            rest = cur
            for t in range(k0, k0 + per_point):
                if count[t] < threshold:
                    pos[t] = cur
                    cur += count[t]
            for s in range(rest, cur, width):
                starts[g] = s
                g += 1
        starts[g] = n
        order = np.empty(n, dtype=np.int64)
        for q in range(n):
            t = tkey[q]
            order[pos[t]] = q
            pos[t] += 1
        return order, starts[: g + 1].copy()


def group_queries(pts: np.ndarray, i1: np.ndarray, i2: np.ndarray, n_points: int, patch: int,
                  width: int = GROUP) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """The runtime's groups: (``order``, ``starts``) as :func:`group_by_point` gives them, but
    a texel with :data:`TEXEL_GROUPING` queries or more gets groups of its own (the grouped
    loop then shares its spatial factors); every group holds queries of one point."""
    per_point = patch * patch
    if (not HAVE_NUMBA or n_points * per_point > _TEXEL_KEYS_PER_QUERY * max(pts.size, 1)
            or pts.size < TEXEL_GROUPING):  # fmt: skip
        return group_by_point(pts, n_points, width)
    tkey = (np.asarray(pts, dtype=np.int64) * patch + i1) * patch + i2
    return _group_texels_nb(tkey, int(n_points), int(per_point), int(width),
                            int(TEXEL_GROUPING))  # fmt: skip


def group_by_point(pts: np.ndarray, n_points: int, width: int = GROUP
                   ) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """Queries sorted by data point and cut into groups of at most ``width`` of one point.

    ``pts`` (n,) int64 in [0, n_points). Returns ``order`` (n,) int64 (stable: queries of a
    point keep their order) and ``starts`` (G + 1,) int64: group g is
    ``order[starts[g]:starts[g + 1]]``.
    """
    if width < 1:
        raise ValueError(f"width must be >= 1, got {width}")
    if HAVE_NUMBA:
        return _group_nb(np.ascontiguousarray(pts, dtype=np.int64), int(n_points), int(width))
    return _group_numpy(np.asarray(pts, dtype=np.int64), int(width))

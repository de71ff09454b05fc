"""Eq. 6 over a batch of queries grouped by data point: the compiled lookup of the runtime.

:func:`~sparsebtf.runtime.kernels.separable_sum` is the reference: per query q,

    X_q = Σ_s v_s U1[i1_q, l1_s] U2[i2_q, l2_s] r3_q[l3_s] r4_q[l4_s],
    r3_q = Σ_a wl_qa U3[L_qa, :],   r4_q = Σ_b wv_qb U4[V_qb, :]

(the two angular rows interpolated once per query, then one pass over the point's kept
coefficients s). Answered one query at a time, every term is four dependent gathers, and a
point's coefficients are read again by every query that lands on it.

Here the queries are first sorted by data point (a counting sort, O(n + P)) and cut into
groups of at most :data:`GROUP` queries of one point. A group lays its per-query factors out
lane-major — ``T1[l1, j] = U1[i1_j, l1]``, ``T2[l2, j]``, ``R3[l3, j] = r3_j[l3]``,
``R4[l4, j]`` — so one coefficient is read once for the whole group and its term is four
contiguous vector loads and three multiplies across the group's lanes j: SIMD over queries,
not gathers per query. The price is writing the tables (m1 + m2 + n_L + n_V values per
query), so a lone query on a point costs about what it costs in the reference; a renderer's
wavefront (many queries per point) gets the full speed-up, and so do random queries on any
texture with more queries than points. ``benchmarks/bench_lookup.py`` measures both orders
against this machine's gather/FMA floor.

Level of detail per query (fractional τ, :func:`~sparsebtf.runtime.kernels.prefix_weights`)
is kept: the group sums the prefix every lane keeps fully, then the few coefficients some
lanes weigh by clip(τ_j − rank, 0, 1). Values equal the reference's to float32 rounding
(the sums accumulate in the dictionaries' dtype; tests in ``tests/test_wavefront.py``).
"""

from __future__ import annotations

import itertools

import numpy as np

from .._numba import HAVE_NUMBA
from .._numba import numba as _nb

__all__ = [
    "GROUP",
    "finish",
    "group_by_point",
    "grouped_pays",
    "separable_sums",
]

#: Queries per group: lanes of the vector loops (32 float32 = two AVX-512 or four AVX2
#: registers per table row; tables of a UBO2014 group then fit in L1/L2: (10 + 10 + 151 +
#: 151) rows × 32 × 4 bytes = 41 KB).
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

    @_nb.njit(cache=True, nogil=True, inline="always")
    def _lanes(f, m, rows, width):
        # (m, rows) query-major -> (rows, width) lane-major.
        t = np.empty(rows * width, dtype=f.dtype)
        for x in range(rows):
            for j in range(m):
                t[x * width + j] = f[j * rows + x]
        return t

    @_nb.njit(parallel=True, cache=True, nogil=True, fastmath=True)
    def _grouped_nb(vals, locs, offs, memb, d1, d2, d3, d4, pts, i1, i2, li, lw, vi, vw, tau,
                    order, starts, width):  # fmt: skip
        # ``width`` is a run-time value on purpose: with a compile-time trip count LLVM
        # unrolls the lane loops into scalar code instead of vectorising them.
        n = pts.shape[0]
        kl = li.shape[1]
        kv = vi.shape[1]
        m1 = d1.shape[2]
        m2 = d2.shape[2]
        n_l = d3.shape[2]
        n_v = d4.shape[2]
        out = np.empty(n, dtype=np.float64)
        for g in _nb.prange(starts.shape[0] - 1):
            q0 = starts[g]
            m = starts[g + 1] - q0
            p = pts[order[q0]]
            k = memb[p]
            s0 = offs[p]
            cnt = offs[p + 1] - s0
            # Lanes >= m are never read: the tables need no clearing. Each query's factors
            # are built contiguously first (vector loads and stores), then transposed into
            # the lane-major tables: 2.5x faster than writing the tables column by column.
            f1 = np.empty(width * m1, dtype=vals.dtype)
            f2 = np.empty(width * m2, dtype=vals.dtype)
            f3 = np.empty(width * n_l, dtype=vals.dtype)
            f4 = np.empty(width * n_v, dtype=vals.dtype)
            tq = np.empty(width, dtype=np.float64)
            t_lo = np.inf
            t_hi = 0.0
            for j in range(m):
                q = order[q0 + j]
                for x in range(m1):
                    f1[j * m1 + x] = d1[k, i1[q], x]
                for x in range(m2):
                    f2[j * m2 + x] = d2[k, i2[q], x]
                w = lw[q, 0]
                row = li[q, 0]
                for x in range(n_l):
                    f3[j * n_l + x] = w * d3[k, row, x]
                for a in range(1, kl):
                    w = lw[q, a]
                    row = li[q, a]
                    for x in range(n_l):
                        f3[j * n_l + x] += w * d3[k, row, x]
                w = vw[q, 0]
                row = vi[q, 0]
                for x in range(n_v):
                    f4[j * n_v + x] = w * d4[k, row, x]
                for b in range(1, kv):
                    w = vw[q, b]
                    row = vi[q, b]
                    for x in range(n_v):
                        f4[j * n_v + x] += w * d4[k, row, x]
                tq[j] = tau[q]
                t_lo = min(t_lo, tau[q])
                t_hi = max(t_hi, tau[q])
            t1 = _lanes(f1, m, m1, width)
            t2 = _lanes(f2, m, m2, width)
            r3 = _lanes(f3, m, n_l, width)
            r4 = _lanes(f4, m, n_v, width)
            acc = np.zeros(width, dtype=vals.dtype)
            full = min(cnt, np.int64(np.floor(t_lo)))
            for s in range(s0, s0 + full):
                c = locs[s]
                v = vals[s]
                o1 = (c & 0xFF) * width
                o2 = ((c >> 8) & 0xFF) * width
                o3 = ((c >> 16) & 0xFF) * width
                o4 = (c >> 24) * width
                for j in range(m):
                    acc[j] += v * t1[o1 + j] * t2[o2 + j] * r3[o3 + j] * r4[o4 + j]
            # The ranks some lanes keep only partly (fractional or per-query τ).
            for r in range(full, min(cnt, np.int64(np.ceil(t_hi)))):
                c = locs[s0 + r]
                v = vals[s0 + r]
                o1 = (c & 0xFF) * width
                o2 = ((c >> 8) & 0xFF) * width
                o3 = ((c >> 16) & 0xFF) * width
                o4 = (c >> 24) * width
                for j in range(m):
                    f = min(1.0, max(0.0, tq[j] - r))
                    acc[j] += v * f * t1[o1 + j] * t2[o2 + j] * r3[o3 + j] * r4[o4 + j]
            for j in range(m):
                out[order[q0 + j]] = acc[j]
        return out

    @_nb.njit(parallel=True, cache=True, nogil=True, fastmath=True)
    def _per_query_nb(vals, locs, offs, memb, d1, d2, d3, d4, pts, i1, i2, li, lw, vi, vw, tau):
        # The reference's loop, in the dictionaries' dtype, with the fully kept prefix apart
        # from the one partly kept rank (no clip per term).
        n = pts.shape[0]
        kl = li.shape[1]
        kv = vi.shape[1]
        n_l = d3.shape[2]
        n_v = d4.shape[2]
        out = np.empty(n, dtype=np.float64)
        for q in _nb.prange(n):
            p = pts[q]
            k = memb[p]
            s0 = offs[p]
            cnt = offs[p + 1] - s0
            t = tau[q]
            r3 = np.zeros(n_l, dtype=vals.dtype)
            r4 = np.zeros(n_v, dtype=vals.dtype)
            for a in range(kl):
                w = lw[q, a]
                row = li[q, a]
                for x in range(n_l):
                    r3[x] += w * d3[k, row, x]
            for b in range(kv):
                w = vw[q, b]
                row = vi[q, b]
                for x in range(n_v):
                    r4[x] += w * d4[k, row, x]
            u1 = d1[k, i1[q]]
            u2 = d2[k, i2[q]]
            acc = np.zeros(1, dtype=vals.dtype)[0]
            full = min(cnt, np.int64(np.floor(t)))
            for s in range(s0, s0 + full):
                c = locs[s]
                acc += (vals[s] * u1[c & 0xFF] * u2[(c >> 8) & 0xFF] * r3[(c >> 16) & 0xFF]
                        * r4[c >> 24])  # fmt: skip
            if full < cnt and t > full:
                s = s0 + full
                c = locs[s]
                acc += (vals[s] * min(1.0, t - full) * u1[c & 0xFF] * u2[(c >> 8) & 0xFF]
                        * r3[(c >> 16) & 0xFF] * r4[c >> 24])  # fmt: skip
            out[q] = acc
        return out


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


#: Cycles of the two loops, measured on a Xeon (Sapphire Rapids, AVX-512) with
#: ``benchmarks/bench_lookup.py``: a table entry written per query (grouped), a coefficient
#: summed for a whole group (grouped), the interpolated rows built (per query) and a
#: coefficient summed for one query (per query). Only their ratios pick the loop.
_TABLE_ENTRY, _GROUP_TERM, _ROW_BUILD, _QUERY_TERM = 0.65, 14.0, 200.0, 2.7


def grouped_pays(ch: dict[str, np.ndarray], tau: np.ndarray, kl: int, kv: int,
                 queries_per_group: float) -> bool:  # fmt: skip
    """Whether the grouped loop is cheaper than the per-query one for this channel: its
    tables cost (m1 + m2 + kl·n_L + kv·n_V) entries per query, its sum a group's term per
    coefficient, shared by the group's queries; the per-query loop pays every term alone."""
    m1, m2 = ch["dict1"].shape[2], ch["dict2"].shape[2]
    n_l, n_v = ch["dict3"].shape[2], ch["dict4"].shape[2]
    off = ch["offsets"]
    widest = float(np.max(off[1:] - off[:-1], initial=0))
    if not tau.size:
        return False
    # A group sums up to its largest τ; one query sums up to its own.
    group_terms = min(float(np.max(tau)), widest)
    query_terms = min(float(np.mean(tau)), widest)
    grouped = (_TABLE_ENTRY * (m1 + m2 + kl * n_l + kv * n_v)
               + _GROUP_TERM * group_terms / max(queries_per_group, 1.0))  # fmt: skip
    return grouped < _ROW_BUILD + _QUERY_TERM * query_terms


def separable_sums(
    ch: dict[str, np.ndarray],
    pts: np.ndarray,
    i1: np.ndarray,
    i2: np.ndarray,
    li: np.ndarray,
    lw: np.ndarray,
    vi: np.ndarray,
    vw: np.ndarray,
    tau: np.ndarray,
    groups: tuple[np.ndarray, np.ndarray] | None,
    loop: str = "auto",
    width: int = GROUP,
) -> np.ndarray:
    """Eq. 6 for every query, (n,) float64, equal to
    :func:`~sparsebtf.runtime.kernels.separable_sum` (same arguments; ``tau`` (n,) float64)
    to float32 rounding. ``loop``: "grouped" (``groups`` from :func:`group_by_point` with
    the same ``width``), "query" (one query at a time) or "auto" (:func:`grouped_pays`).
    Compiled only: needs numba."""
    if not HAVE_NUMBA:  # pragma: no cover - the caller picks the reference instead
        raise RuntimeError("the compiled lookup needs numba")
    dt = ch["values"].dtype
    lw, vw = lw.astype(dt), vw.astype(dt)
    if loop == "auto":
        per = pts.size / max(groups[1].size - 1, 1) if groups is not None else 1.0
        loop = "grouped" if groups is not None and grouped_pays(
            ch, tau, li.shape[1], vi.shape[1], per) else "query"  # fmt: skip
    args = (ch["values"], ch["locations"], ch["offsets"], ch["membership"],
            ch["dict1"], ch["dict2"], ch["dict3"], ch["dict4"], pts, i1, i2, li, lw, vi, vw,
            tau)  # fmt: skip
    if loop == "grouped":
        if groups is None:
            raise ValueError("the grouped loop needs groups (group_by_point)")
        return _grouped_nb(*args, groups[0], groups[1], int(width))
    if loop != "query":
        raise ValueError(f"loop must be 'auto', 'grouped' or 'query', got {loop!r}")
    return _per_query_nb(*args)


if HAVE_NUMBA:

    @_nb.njit(parallel=True, cache=True, nogil=True, fastmath=True)
    def _finish_nb(x, li, lw, vi, vw, mean, std, bound, m, log_offset, bounded, rgb):
        # de-standardise with the interpolated statistics (Eq. 6), YUV -> RGB, the bound
        # interpolated with the same weights, exp: the reference's NumPy steps, per query.
        n = x.shape[0]
        kl = li.shape[1]
        kv = vi.shape[1]
        s = mean.shape[0]
        out = np.empty((n, 3), dtype=np.float32)
        for q in _nb.prange(n):
            yuv = np.zeros(3)
            bq = 0.0
            for c in range(3):
                sc = c if s == 3 else 0
                mu = 0.0
                sd = 0.0
                for a in range(kl):
                    for b in range(kv):
                        w = lw[q, a] * vw[q, b]
                        mu += w * mean[sc, li[q, a], vi[q, b]]
                        sd += w * std[sc, li[q, a], vi[q, b]]
                        if c == 0 and bounded:
                            bq += w * bound[li[q, a], vi[q, b]]
                yuv[c] = x[q, c] * sd + mu
            for c in range(3):
                v = m[c, 0] * yuv[0] + m[c, 1] * yuv[1] + m[c, 2] * yuv[2]
                if bounded:
                    v = min(v, bq)
                out[q, c] = np.exp(v) - log_offset if rgb else yuv[c]
        return out


def finish(x: np.ndarray, li: np.ndarray, lw: np.ndarray, vi: np.ndarray, vw: np.ndarray,
           mean: np.ndarray, std: np.ndarray, bound: np.ndarray | None, matrix: np.ndarray,
           log_offset: float, rgb: bool) -> np.ndarray:  # fmt: skip
    """The runtime's steps after the sums, fused per query: ``x`` (n, 3) standardised Y, U, V
    sums → (n, 3) float32 linear RGB (``rgb``) or log-YUV. ``mean``/``std`` (S, L, V),
    ``bound`` (L, V) or None, ``matrix`` the (3, 3) YUV → RGB matrix."""
    b = np.zeros((1, 1)) if bound is None else bound
    return _finish_nb(x, li, lw, vi, vw, mean, std, b, np.ascontiguousarray(matrix),
                      float(log_offset), bound is not None, bool(rgb))  # fmt: skip

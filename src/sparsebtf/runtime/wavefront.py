"""Eq. 6 over a batch of queries grouped by data point: the compiled lookup of the runtime.

:func:`~sparsebtf.runtime.kernels.separable_sum` is the reference: per query q,

    X_q = Σ_s v_s U1[i1_q, l1_s] U2[i2_q, l2_s] r3_q[l3_s] r4_q[l4_s],
    r3_q = Σ_a wl_qa U3[L_qa, :],   r4_q = Σ_b wv_qb U4[V_qb, :]

(the two angular rows interpolated once per query, then one pass over the point's kept
coefficients s). Answered one query at a time, every term is four dependent gathers, and a
point's coefficients are read again by every query that lands on it.

Both loops work on each point's compact factors (:mod:`.compact`): only the (l1, l2) pairs,
light columns and view columns the point's coefficients name, in order of first use, so a
query builds t12[e] = U1[i1, l1_e]·U2[i2, l2_e], r3 and r4 at those columns only (a level of
detail τ' needs a prefix of each list) and a term is v·t12[e]·r3[a]·r4[b].

The queries are first sorted by data point (a counting sort, O(n + P)) and cut into groups of
at most :data:`GROUP` queries of one point. A group lays its per-query factors out
lane-major — ``T12[e, j]``, ``R3[a, j]``, ``R4[b, j]`` — so one coefficient is read once for
the whole group and its term is three contiguous vector loads and three multiplies across the
group's lanes j: SIMD over queries, not gathers per query. The price is transposing the
factors, so a lone query on a point is answered by the per-query loop instead
(:func:`grouped_pays`); a renderer's wavefront (many queries per point) gets the full
speed-up, and so do random queries on any texture with more queries than points.
``benchmarks/bench_lookup.py`` measures both orders against this machine's gather/FMA floor.

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
from .compact import CompactLayout, channel_layout

__all__ = [
    "GROUP",
    "finish",
    "group_by_point",
    "grouped_pays",
    "separable_sums",
]

#: Queries per group: lanes of the vector loops (32 float32 = two AVX-512 or four AVX2
#: registers per table row; the tables of a UBO2014 group fit in L1/L2 even when every mode
#: is whole: (100 + 151 + 151) rows × 32 × 4 bytes = 51 KB).
GROUP = 32

#: Queries per task of the per-query loop, groups per task of the grouped one (scratch is
#: allocated once per task).
_CHUNK = 256
_TASK = 16
_LOW16, _LOW8, _AT3, _AT4 = np.uint64(0xFFFF), np.uint64(0xFF), np.uint64(16), np.uint64(24)


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

    # Indexing note for every loop below: an index numba cannot prove non-negative (o + j,
    # j·n + e) gets a wraparound test per access, and that test stops LLVM from vectorising
    # the loop (measured: 6x slower lane sums). So the loops index 1-D views (a slice taken
    # once) with the bare loop counter, which is known to be >= 0.

    @_nb.njit(cache=True, nogil=True, inline="always")
    def _lanes(t, f, m, rows, width):
        # (m, rows) query-major f -> (rows, width) lane-major t.
        for x in range(rows):
            tx = t[x * width:(x + 1) * width]
            fx = f[x:]
            for j in range(m):
                tx[j] = fx[j * rows]

    @_nb.njit(cache=True, nogil=True, inline="always")
    def _factors(f12, f3, f4, st, k, p1, p2, n12, c3, n3, c4, n4, d1, d2, d3, d4, u1, u2, li,
                 lw, vi, vw):  # fmt: skip
        # One query's compact factors, entry x at f[x * st] (st = 1: a query's own rows; st =
        # the group width: a lane of the lane-major tables): f12 the pairs' products U1·U2,
        # f3 and f4 the light and view rows interpolated at the point's columns (p1, p2, c3,
        # c4: the point's lists). A list as long as the mode is the whole mode in order
        # (compact.py): contiguous loads instead of gathers. Unsigned strides: numba does not
        # test an unsigned index for wraparound.
        us = np.uint64(st)
        r1 = d1[k, u1]
        r2 = d2[k, u2]
        m2 = r2.shape[0]
        if n12 == r1.shape[0] * m2:
            for x in range(r1.shape[0]):
                a = r1[x]
                fx = f12[x * m2 * st:]
                for y in range(np.uint64(m2)):
                    fx[y * us] = a * r2[y]
        else:
            for e in range(np.uint64(n12)):
                f12[e * us] = r1[p1[e]] * r2[p2[e]]
        _row(f3, us, n3, c3, d3, k, li, lw)
        _row(f4, us, n4, c4, d4, k, vi, vw)

    @_nb.njit(cache=True, nogil=True, inline="always")
    def _row(f, us, cnt, col, d, k, rows, w):
        # f[x·us] = Σ_a w_a U[rows_a, col_x], x < cnt: Eq. 6's row at the point's columns.
        # One and two neighbours (nearest, linear) write each entry once; more add up.
        dense = cnt == d.shape[2]
        r0 = d[k, rows[0]]
        w0 = w[0]
        if rows.shape[0] == 2:
            r1 = d[k, rows[1]]
            w1 = w[1]
            if dense:
                for x in range(np.uint64(cnt)):
                    f[x * us] = w0 * r0[x] + w1 * r1[x]
            else:
                for x in range(np.uint64(cnt)):
                    c = col[x]
                    f[x * us] = w0 * r0[c] + w1 * r1[c]
            return
        if dense:
            for x in range(np.uint64(cnt)):
                f[x * us] = w0 * r0[x]
        else:
            for x in range(np.uint64(cnt)):
                f[x * us] = w0 * r0[col[x]]
        for a in range(1, rows.shape[0]):
            wa = w[a]
            ra = d[k, rows[a]]
            if dense:
                for x in range(np.uint64(cnt)):
                    f[x * us] += wa * ra[x]
            else:
                for x in range(np.uint64(cnt)):
                    f[x * us] += wa * ra[col[x]]

    @_nb.njit(parallel=True, cache=True, nogil=True, fastmath=True)
    def _grouped_nb(vals, code, need, offs, memb, p1, p2, o12, c3, o3, c4, o4, d1, d2, d3, d4,
                    pts, i1, i2, li, lw, vi, vw, tau, order, starts, width, w12, w3,
                    w4):  # fmt: skip
        # ``width`` is a run-time value on purpose: with a compile-time trip count LLVM
        # unrolls the lane loops into scalar code instead of vectorising them. Scratch is
        # allocated once per task of _TASK groups (w12, w3, w4: the longest lists).
        n = pts.shape[0]
        n_groups = starts.shape[0] - 1
        out = np.empty(n, dtype=np.float64)
        dt = vals.dtype
        for task in _nb.prange((n_groups + _TASK - 1) // _TASK):
            tq = np.empty(width, dtype=np.float64)
            acc = np.empty(width, dtype=dt)
            f12 = np.empty(width * w12, dtype=dt)
            f3 = np.empty(width * w3, dtype=dt)
            f4 = np.empty(width * w4, dtype=dt)
            t12 = np.empty(width * w12, dtype=dt)
            r3 = np.empty(width * w3, dtype=dt)
            r4 = np.empty(width * w4, dtype=dt)
            for g in range(task * _TASK, min(n_groups, (task + 1) * _TASK)):
                _group(g, vals, code, need, offs, memb, p1, p2, o12, c3, o3, c4, o4, d1, d2,
                       d3, d4, i1, i2, li, lw, vi, vw, tau, order, starts, pts, width, out, tq,
                       acc, f12, f3, f4, t12, r3, r4)  # fmt: skip
        return out

    @_nb.njit(cache=True, nogil=True, fastmath=True)
    def _group(g, vals, code, need, offs, memb, p1, p2, o12, c3, o3, c4, o4, d1, d2, d3, d4,
               i1, i2, li, lw, vi, vw, tau, order, starts, pts, width, out, tq, acc, f12, f3,
               f4, t12, r3, r4):  # fmt: skip
        q0 = starts[g]
        m = starts[g + 1] - q0
        p = pts[order[q0]]
        k = memb[p]
        s0 = offs[p]
        cnt = offs[p + 1] - s0
        t_lo = np.inf
        t_hi = 0.0
        for j in range(m):
            t = tau[order[q0 + j]]
            tq[j] = t
            t_lo = min(t_lo, t)
            t_hi = max(t_hi, t)
        top = min(cnt, np.int64(np.ceil(t_hi)))
        if top == 0:
            for j in range(m):
                out[order[q0 + j]] = 0.0
            return
        # The lists the group's longest prefix uses (first-use order: a prefix).
        nd = need[s0 + top - 1]
        n12 = np.int64(nd & 0xFFFFF)
        n3 = np.int64((nd >> 20) & 0xFFFFF)
        n4 = np.int64(nd >> 40)
        pp1, pp2 = p1[o12[p]:], p2[o12[p]:]
        pc3, pc4 = c3[o3[p]:], c4[o4[p]:]
        # Lanes >= m are never read: the tables need no clearing. Each query's factors are
        # built contiguously first, then transposed into the lane-major tables: 2.5x faster
        # than writing the tables column by column.
        for j in range(m):
            q = order[q0 + j]
            _factors(t12[j:], r3[j:], r4[j:], width, k, pp1, pp2, n12, pc3, n3, pc4, n4, d1, d2,
                     d3, d4, i1[q], i2[q], li[q], lw[q], vi[q], vw[q])  # fmt: skip
        for j in range(m):
            acc[j] = 0.0
        full = min(cnt, np.int64(np.floor(t_lo)))
        for s in range(s0, top + s0):
            c = code[s]
            v = vals[s]
            o = (c & 0xFFFF) * width
            a12 = t12[o:o + width]
            o = ((c >> 16) & 0xFF) * width
            a3 = r3[o:o + width]
            o = (c >> 24) * width
            a4 = r4[o:o + width]
            if s < s0 + full:
                for j in range(m):
                    acc[j] += v * a12[j] * a3[j] * a4[j]
            else:  # a rank some lanes keep only partly (fractional or per-query τ)
                r = s - s0
                for j in range(m):
                    f = min(1.0, max(0.0, tq[j] - r))
                    acc[j] += v * f * a12[j] * a3[j] * a4[j]
        for j in range(m):
            out[order[q0 + j]] = acc[j]

    @_nb.njit(cache=True, nogil=True, inline="always")
    def _term(v, c, t12, r3, r4):
        # v·t12[e]·r3[a]·r4[b] of compact code c = e | a<<16 | b<<24, unsigned throughout.
        u = np.uint64(c)
        return v * t12[u & _LOW16] * r3[(u >> _AT3) & _LOW8] * r4[u >> _AT4]

    @_nb.njit(parallel=True, cache=True, nogil=True, fastmath=True)
    def _per_query_nb(vals, code, need, offs, memb, p1, p2, o12, c3, o3, c4, o4, d1, d2, d3,
                      d4, pts, i1, i2, li, lw, vi, vw, tau, w12, w3, w4):  # fmt: skip
        # The reference's loop, in the dictionaries' dtype, over compact factors, with the
        # fully kept prefix apart from the one partly kept rank (no clip per term). Scratch
        # is allocated once per chunk of queries, not per query.
        n = pts.shape[0]
        out = np.empty(n, dtype=np.float64)
        n_chunks = (n + _CHUNK - 1) // _CHUNK
        for ci in _nb.prange(n_chunks):
            t12 = np.empty(w12, dtype=vals.dtype)
            r3 = np.empty(w3, dtype=vals.dtype)
            r4 = np.empty(w4, dtype=vals.dtype)
            for q in range(ci * _CHUNK, min(n, (ci + 1) * _CHUNK)):
                p = pts[q]
                s0 = offs[p]
                cnt = offs[p + 1] - s0
                t = tau[q]
                top = min(cnt, np.int64(np.ceil(t)))
                if top == 0:
                    out[q] = 0.0
                    continue
                nd = need[s0 + top - 1]
                _factors(t12, r3, r4, 1, memb[p], p1[o12[p]:], p2[o12[p]:], np.int64(nd & 0xFFFFF),
                         c3[o3[p]:], np.int64((nd >> 20) & 0xFFFFF), c4[o4[p]:],
                         np.int64(nd >> 40), d1, d2, d3, d4, i1[q], i2[q], li[q], lw[q], vi[q],
                         vw[q])  # fmt: skip
                # The prefix as views from 0 (see the indexing note) and an unsigned code:
                # no wraparound tests. Four partial sums: one would chain every term on
                # the add before it.
                full = min(cnt, np.int64(np.floor(t)))
                cv = code[s0:s0 + top]
                vv = vals[s0:s0 + top]
                a0 = a1 = a2 = a3 = 0.0
                for s in range(0, full - 3, 4):
                    a0 += _term(vv[s], cv[s], t12, r3, r4)
                    a1 += _term(vv[s + 1], cv[s + 1], t12, r3, r4)
                    a2 += _term(vv[s + 2], cv[s + 2], t12, r3, r4)
                    a3 += _term(vv[s + 3], cv[s + 3], t12, r3, r4)
                acc = (a0 + a1) + (a2 + a3)
                for s in range((full // 4) * 4, full):
                    acc += _term(vv[s], cv[s], t12, r3, r4)
                if full < top:
                    acc += min(1.0, t - full) * _term(vv[full], cv[full], t12, r3, r4)
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


#: Relative costs of the two loops, measured with ``benchmarks/bench_lookup.py``'s material
#: on a Xeon (Sapphire Rapids, AVX-512), cycles on one thread: a coefficient summed for a
#: whole group across its lanes, and for one query. Only their ratio picks the loop: the
#: grouped one pays from about four queries per group.
_GROUP_TERM, _QUERY_TERM = 22.0, 5.5


def grouped_pays(ch: dict[str, np.ndarray], tau: np.ndarray, queries_per_group: float
                 ) -> bool:  # fmt: skip
    """Whether the grouped loop is cheaper than the per-query one for this channel. Both
    build a query's compact factors (n12 + kl·n3 + kv·n4 entries, :mod:`.compact`), the
    grouped loop straight into its lane-major tables; its sum costs a group's term per
    coefficient, shared by the group's queries, where the per-query loop pays every term
    alone."""
    if not tau.size:
        return False
    off = ch["offsets"]
    widest = float(np.max(off[1:] - off[:-1], initial=0))
    # A group sums up to its largest τ; one query sums up to its own.
    group_terms = min(float(np.max(tau)), widest)
    query_terms = min(float(np.mean(tau)), widest)
    # Both loops build the same factors per query: only the sums differ.
    return _GROUP_TERM * group_terms / max(queries_per_group, 1.0) < _QUERY_TERM * query_terms


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
    layout: CompactLayout | None = None,
) -> np.ndarray:
    """Eq. 6 for every query, (n,) float64, equal to
    :func:`~sparsebtf.runtime.kernels.separable_sum` (same arguments; ``tau`` (n,) float64)
    to float32 rounding. ``loop``: "grouped" (``groups`` from :func:`group_by_point` with
    the same ``width``), "query" (one query at a time) or "auto" (:func:`grouped_pays`).
    ``layout``: the channel's :func:`~sparsebtf.runtime.compact.channel_layout` (built here
    when not given; callers that ask often keep it). Compiled only: needs numba."""
    if not HAVE_NUMBA:  # pragma: no cover - the caller picks the reference instead
        raise RuntimeError("the compiled lookup needs numba")
    if layout is None:
        layout = channel_layout(ch)
    dt = ch["values"].dtype
    lw, vw = lw.astype(dt), vw.astype(dt)
    if loop == "auto":
        per = pts.size / max(groups[1].size - 1, 1) if groups is not None else 1.0
        loop = "grouped" if groups is not None and grouped_pays(
            ch, tau, per) else "query"  # fmt: skip
    lay = layout
    args = (ch["values"], lay.code, lay.need, ch["offsets"], ch["membership"], lay.pair1,
            lay.pair2, lay.o12, lay.col3, lay.o3, lay.col4, lay.o4, ch["dict1"], ch["dict2"],
            ch["dict3"], ch["dict4"], pts, i1, i2, li, lw, vi, vw, tau)  # fmt: skip
    if loop == "grouped":
        if groups is None:
            raise ValueError("the grouped loop needs groups (group_by_point)")
        return _grouped_nb(*args, groups[0], groups[1], int(width),
                           *(max(w, 1) for w in lay.widest))  # fmt: skip
    if loop != "query":
        raise ValueError(f"loop must be 'auto', 'grouped' or 'query', got {loop!r}")
    return _per_query_nb(*args, *(max(w, 1) for w in lay.widest))


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

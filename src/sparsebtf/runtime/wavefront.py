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

The queries are first sorted by data point (a counting sort, O(n + P)), their inputs put in
that order once (:func:`.grouping.rows_in_order`), and cut into groups of at most
:data:`.grouping.GROUP` queries
of one point. A group writes its per-query factors lane-major — ``T12[e, j]``, ``R3[a, j]``,
``R4[b, j]`` — so one coefficient is read once for the whole group and its term is three
contiguous vector loads across the group's lanes j: SIMD over queries, not gathers per query.
Where every lane sums the point's whole list, the coefficients go by (light, view) column
pair instead: Σ_pairs R3[a]·R4[b]·Σ v·T12[e], one table load per coefficient, the group's 32
lanes held in vector registers (:mod:`sparsebtf._lanes`). A texel with many queries
(:data:`.grouping.TEXEL_GROUPING`) gets groups of its own
(:func:`.grouping.group_queries`): the group's T12 is one row, a pair's Σ v·t12 one scalar
for every lane (and for the next groups on that texel), so a coefficient costs a scalar term
per group and only the angular rows are built per lane.
A lone query on a point pays a group's vector overhead for one lane, so it takes the
per-query loop (:func:`grouped_pays`); a renderer's wavefront (many queries per point) gets
the full speed-up, and so do random queries on any texture with more queries than points.
``benchmarks/bench_lookup.py`` measures both orders against this machine's gather/FMA floor.

Level of detail per query (fractional τ, :func:`~sparsebtf.runtime.kernels.prefix_weights`)
is kept: the group sums the prefix every lane keeps fully, then the few coefficients some
lanes weigh by clip(τ_j − rank, 0, 1). Values equal the reference's to float32 rounding
(the sums accumulate in the dictionaries' dtype; tests in ``tests/test_wavefront.py``).
"""

from __future__ import annotations

import numpy as np

from .._numba import HAVE_NUMBA
from .._numba import numba as _nb
from .compact import CompactLayout, channel_layout
from .grouping import GROUP

if HAVE_NUMBA:
    from .._lanes import lanes_fma, lanes_load, lanes_mul, lanes_store, lanes_zeros

__all__ = ["grouped_pays", "separable_sums"]

#: Queries per task of the per-query loop, groups per task of the grouped one (scratch is
#: allocated once per task).
_CHUNK = 256
_TASK = 16
#: The unsigned masks and shifts of compact.py's packed words (code, need, pab).
_LOW8, _LOW16, _LOW20 = np.uint64(0xFF), np.uint64(0xFFFF), np.uint64(0xFFFFF)
_SH16, _SH20, _SH24, _SH40 = np.uint64(16), np.uint64(20), np.uint64(24), np.uint64(40)
#: Lane offsets of the register sums (GROUP = 2 Lanes values of 16).
_U0, _U1, _U16, _U32 = np.uint64(0), np.uint64(1), np.uint64(16), np.uint64(32)


if HAVE_NUMBA:

    # Indexing note for every loop below: numba tests every signed index for wraparound
    # (a negative index counts from the end), and that test stops LLVM from vectorising the
    # loop (measured: 6x slower lane sums); a view taken per query (d[k, row]) costs a
    # reference count. So the hot loops index with unsigned integers (np.uint64: no test).

    @_nb.njit(cache=True, nogil=True, inline="always")
    def _split_code(c):
        # a coefficient's compact code e | a<<16 | b<<24 as unsigned (e, a, b)
        u = np.uint64(c)
        return u & _LOW16, (u >> _SH16) & _LOW8, u >> _SH24

    @_nb.njit(cache=True, nogil=True, inline="always")
    def _split_need(nd):
        # a prefix's list lengths n12 | n3<<20 | n4<<40 as unsigned (n12, n3, n4)
        u = np.uint64(nd)
        return u & _LOW20, (u >> _SH20) & _LOW20, u >> _SH40

    @_nb.njit(cache=True, nogil=True, inline="always")
    def _factors(t12, t3, t4, j, st, k, p1, p2, a12, n12, c3, a3, n3, c4, a4, n4, d1, d2, d3,
                 d4, u1, u2, li, lw, vi, vw, q):  # fmt: skip
        # Query q's compact factors, entry x at t[j + x·st] (st = 1: a query's own rows; st =
        # the group width: lane j of the lane-major tables): t12 the pairs' products U1·U2,
        # t3 and t4 the light and view rows interpolated at the point's columns (the lists
        # p1, p2 from a12, c3 from a3, c4 from a4). A list as long as the mode is the whole
        # mode in order (compact.py): contiguous loads instead of gathers. All unsigned.
        _products(t12, j, st, k, p1, p2, a12, n12, d1, d2, u1, u2)
        _row(t3, j, st, n3, c3, a3, d3, k, li, lw, q)
        _row(t4, j, st, n4, c4, a4, d4, k, vi, vw, q)

    @_nb.njit(cache=True, nogil=True, inline="always")
    def _products(t12, j, st, k, p1, p2, a12, n12, d1, d2, u1, u2):
        # t12[j + e·st] = U1[i1, l1_e]·U2[i2, l2_e] over the point's pair list (or all pairs)
        m1 = np.uint64(d1.shape[2])
        m2 = np.uint64(d2.shape[2])
        if n12 == m1 * m2:
            for x in range(m1):
                f = d1[k, u1, x]
                for y in range(m2):
                    t12[j + (x * m2 + y) * st] = f * d2[k, u2, y]
        else:
            for e in range(n12):
                t12[j + e * st] = d1[k, u1, p1[a12 + e]] * d2[k, u2, p2[a12 + e]]

    @_nb.njit(cache=True, nogil=True, inline="always")
    def _rows34(r3, r4, a3, a4, lane):
        # r3[a]·r4[b] of a (light, view) pair on 16 lanes from ``lane`` (lane-major tables)
        return lanes_mul(lanes_load(r3, a3 + lane), lanes_load(r4, a4 + lane))

    @_nb.njit(cache=True, nogil=True, inline="always")
    def _put32(acc, x0, x1, out, order, q0, m):
        # a group's two Lanes sums to the rows of its m queries
        lanes_store(acc, _U0, x0)
        lanes_store(acc, _U16, x1)
        for j in range(m):
            out[order[q0 + j]] = acc[j]

    @_nb.njit(cache=True, nogil=True, inline="always")
    def _row(t, j, st, cnt, col, a0, d, k, rows, w, q):
        # t[j + x·st] = Σ_a w[q, a] U[rows[q, a], col_x], x < cnt: Eq. 6's row at the point's
        # columns. One and two neighbours (nearest, linear) write each entry once.
        dense = cnt == np.uint64(d.shape[2])
        r0 = np.uint64(rows[q, 0])
        w0 = w[q, 0]
        if rows.shape[1] == 2:
            r1 = np.uint64(rows[q, 1])
            w1 = w[q, 1]
            if dense:
                for x in range(cnt):
                    t[j + x * st] = w0 * d[k, r0, x] + w1 * d[k, r1, x]
            else:
                for x in range(cnt):
                    c = np.uint64(col[a0 + x])
                    t[j + x * st] = w0 * d[k, r0, c] + w1 * d[k, r1, c]
            return
        for x in range(cnt):
            c = x if dense else np.uint64(col[a0 + x])
            t[j + x * st] = w0 * d[k, r0, c]
        for a in range(1, rows.shape[1]):
            ra = np.uint64(rows[q, a])
            wa = w[q, a]
            for x in range(cnt):
                c = x if dense else np.uint64(col[a0 + x])
                t[j + x * st] += wa * d[k, ra, c]

    @_nb.njit(parallel=True, cache=True, nogil=True, fastmath=True)
    def _grouped_nb(vals, code, need, offs, memb, p1, p2, o12, c3, o3, c4, o4, d1, d2, d3, d4,
                    pts, i1, i2, li, lw, vi, vw, tau, order, starts, width, w12, w3, w4,
                    pvals, pe12, pab, pstart, opair, wpairs):  # fmt: skip
        # ``width`` is a run-time value on purpose: with a compile-time trip count LLVM
        # unrolls the lane loops into scalar code instead of vectorising them. Scratch is
        # allocated once per task of _TASK groups (w12, w3, w4: the longest lists). The
        # group's body stays in this function: a call per group passing the ~40 arrays cost
        # ~130 cycles per query.
        n = pts.shape[0]
        n_groups = starts.shape[0] - 1
        out = np.empty(n, dtype=np.float64)
        dt = vals.dtype
        for task in _nb.prange((n_groups + _TASK - 1) // _TASK):
            tq = np.empty(width, dtype=np.float64)
            acc = np.empty(width, dtype=dt)
            inner = np.empty(width, dtype=dt)
            t12 = np.empty(width * w12, dtype=dt)
            r3 = np.empty(width * w3, dtype=dt)
            r4 = np.empty(width * w4, dtype=dt)
            psum = np.empty(wpairs, dtype=dt)  # a texel's pair sums, kept for its next group
            last = np.int64(-1)
            for g in range(task * _TASK, min(n_groups, (task + 1) * _TASK)):
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
                    continue
                # The lists the group's longest prefix uses (first-use order: a prefix).
                n12, n3, n4 = _split_need(need[s0 + top - 1])
                ku = np.uint64(k)
                uw = np.uint64(width)
                um = np.uint64(m)
                full = min(cnt, np.int64(np.floor(t_lo)))
                qa = order[q0]
                one_texel = True
                for j in range(1, m):
                    q = order[q0 + j]
                    one_texel &= (i1[q] == i1[qa]) & (i2[q] == i2[qa])
                if full == cnt and uw == _U32 and one_texel:
                    # Every lane sums the whole list and every lane is on one texel (queries
                    # grouped by texel, group_by_point): the spatial factors are the group's,
                    # so a pair's Σ v·t12 is one scalar for all lanes — and for the next
                    # groups on the same texel, which reuse it — and only the angular rows
                    # are per lane.
                    r0 = opair[p]
                    texel = (p * d1.shape[1] + i1[qa]) * d2.shape[1] + i2[qa]
                    if texel != last:
                        last = texel
                        _products(t12, _U0, _U1, ku, p1, p2, np.uint64(o12[p]), n12, d1, d2,
                                  np.uint64(i1[qa]), np.uint64(i2[qa]))  # fmt: skip
                        for r in range(r0, opair[p + 1]):
                            s = pstart[r]
                            sv = pvals[s] * t12[np.uint64(pe12[s])]
                            for s in range(pstart[r] + 1, pstart[r + 1]):
                                sv += pvals[s] * t12[np.uint64(pe12[s])]
                            psum[r - r0] = sv
                    for j in range(um):
                        q = order[q0 + j]
                        _row(r3, j, uw, n3, c3, np.uint64(o3[p]), d3, ku, li, lw, q)
                        _row(r4, j, uw, n4, c4, np.uint64(o4[p]), d4, ku, vi, vw, q)
                    x0 = lanes_zeros(acc)
                    x1 = lanes_zeros(acc)
                    for r in range(r0, opair[p + 1]):
                        ab = np.uint64(pab[r])
                        a3, a4 = (ab & _LOW16) * uw, (ab >> _SH16) * uw
                        sv = psum[r - r0]
                        x0 = lanes_fma(x0, sv, _rows34(r3, r4, a3, a4, _U0))
                        x1 = lanes_fma(x1, sv, _rows34(r3, r4, a3, a4, _U16))
                    _put32(acc, x0, x1, out, order, q0, m)
                    continue
                # Lanes >= m are never read: the tables need no clearing.
                for j in range(m):
                    q = order[q0 + j]
                    _factors(t12, r3, r4, np.uint64(j), uw, ku, p1, p2, np.uint64(o12[p]), n12,
                             c3, np.uint64(o3[p]), n3, c4, np.uint64(o4[p]), n4, d1, d2, d3,
                             d4, np.uint64(i1[q]), np.uint64(i2[q]), li, lw, vi, vw,
                             q)  # fmt: skip
                for j in range(um):
                    acc[j] = 0.0
                if full == cnt and uw == _U32:
                    # Every lane sums the whole list: by (light, view) column pair, one table
                    # load per coefficient and the pair's r3·r4 once (compact.py); the 32
                    # lanes as two Lanes values, held in registers (_lanes.py).
                    x0 = lanes_zeros(acc)
                    x1 = lanes_zeros(acc)
                    for r in range(opair[p], opair[p + 1]):
                        ab = np.uint64(pab[r])
                        a3, a4 = (ab & _LOW16) * uw, (ab >> _SH16) * uw
                        s0 = lanes_zeros(acc)
                        s1 = lanes_zeros(acc)
                        for s in range(pstart[r], pstart[r + 1]):
                            v = pvals[s]
                            a1 = np.uint64(pe12[s]) * uw
                            s0 = lanes_fma(s0, v, lanes_load(t12, a1))
                            s1 = lanes_fma(s1, v, lanes_load(t12, a1 + _U16))
                        x0 = lanes_fma(x0, s0, _rows34(r3, r4, a3, a4, _U0))
                        x1 = lanes_fma(x1, s1, _rows34(r3, r4, a3, a4, _U16))
                    _put32(acc, x0, x1, out, order, q0, m)
                    continue
                if full == cnt:  # the same for other widths, lane loops through memory
                    for r in range(opair[p], opair[p + 1]):
                        ab = np.uint64(pab[r])
                        a3, a4 = (ab & _LOW16) * uw, (ab >> _SH16) * uw
                        for j in range(um):
                            inner[j] = 0.0
                        for s in range(pstart[r], pstart[r + 1]):
                            v = pvals[s]
                            a1 = np.uint64(pe12[s]) * uw
                            for j in range(um):
                                inner[j] += v * t12[a1 + j]
                        for j in range(um):
                            acc[j] += inner[j] * r3[a3 + j] * r4[a4 + j]
                    for j in range(m):
                        out[order[q0 + j]] = acc[j]
                    continue
                # Two terms per pass over the lanes: half the read-modify-writes of acc.
                for s in range(s0, s0 + full - 1, 2):
                    e, a, b = _split_code(code[s])
                    v = vals[s]
                    a1, a3, a4 = e * uw, a * uw, b * uw
                    e, a, b = _split_code(code[s + 1])
                    w = vals[s + 1]
                    b1, b3, b4 = e * uw, a * uw, b * uw
                    for j in range(um):
                        acc[j] += (v * t12[a1 + j] * r3[a3 + j] * r4[a4 + j]
                                   + w * t12[b1 + j] * r3[b3 + j] * r4[b4 + j])  # fmt: skip
                for s in range(s0 + full - full % 2, s0 + top):
                    e, a, b = _split_code(code[s])
                    v = vals[s]
                    a1, a3, a4 = e * uw, a * uw, b * uw
                    if s < s0 + full:
                        for j in range(um):
                            acc[j] += v * t12[a1 + j] * r3[a3 + j] * r4[a4 + j]
                    else:  # a rank some lanes keep only partly (fractional or per-query τ)
                        r = s - s0
                        for j in range(um):
                            f = min(1.0, max(0.0, tq[j] - r))
                            acc[j] += v * f * t12[a1 + j] * r3[a3 + j] * r4[a4 + j]
                for j in range(m):
                    out[order[q0 + j]] = acc[j]
        return out

    @_nb.njit(cache=True, nogil=True, inline="always")
    def _term(v, c, t12, r3, r4):
        # v·t12[e]·r3[a]·r4[b] of compact code c = e | a<<16 | b<<24, unsigned throughout.
        e, a, b = _split_code(c)
        return v * t12[e] * r3[a] * r4[b]

    @_nb.njit(parallel=True, cache=True, nogil=True, fastmath=True)
    def _per_query_nb(vals, code, need, offs, memb, p1, p2, o12, c3, o3, c4, o4, d1, d2, d3,
                      d4, pts, i1, i2, li, lw, vi, vw, tau, w12, w3, w4):  # fmt: skip
        # The reference's loop over compact factors (terms in the dictionaries' dtype, summed
        # in float64), with the fully kept prefix apart from the one partly kept rank (no
        # clip per term). Scratch is allocated once per chunk of queries, not per query.
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
                n12, n3, n4 = _split_need(need[s0 + top - 1])
                _factors(t12, r3, r4, np.uint64(0), np.uint64(1), np.uint64(memb[p]), p1, p2,
                         np.uint64(o12[p]), n12, c3, np.uint64(o3[p]), n3, c4, np.uint64(o4[p]),
                         n4, d1, d2, d3, d4, np.uint64(i1[q]), np.uint64(i2[q]), li, lw, vi, vw,
                         q)  # fmt: skip
                # the prefix as views from 0: no wraparound tests (see the indexing note)
                full = min(cnt, np.int64(np.floor(t)))
                cv = code[s0:s0 + top]
                vv = vals[s0:s0 + top]
                acc = 0.0
                for s in range(full):
                    acc += _term(vv[s], cv[s], t12, r3, r4)
                if full < top:
                    acc += min(1.0, t - full) * _term(vv[full], cv[full], t12, r3, r4)
                out[q] = acc
        return out



#: Relative costs of the two loops, measured on ``benchmarks/bench_lookup.py``'s captured
#: material on an AMD EPYC (Zen 4, AVX-512), cycles on one thread: a coefficient summed for a
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
    to float32 rounding. ``loop``: "grouped" (``groups`` from :func:`.grouping.group_by_point` with
    the same ``width``), "query" (one query at a time) or "auto" (:func:`grouped_pays`).
    ``layout``: the channel's :func:`~sparsebtf.runtime.compact.channel_layout` (built here
    when not given; callers that ask often keep it). Compiled only: needs numba."""
    if not HAVE_NUMBA:  # pragma: no cover - the caller picks the reference instead
        raise RuntimeError("the compiled lookup needs numba")
    if layout is None:
        layout = channel_layout(ch)
    dt = ch["values"].dtype
    lw, vw = lw.astype(dt, copy=False), vw.astype(dt, copy=False)
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
            raise ValueError("the grouped loop needs groups (grouping.group_by_point)")
        return _grouped_nb(*args, groups[0], groups[1], int(width),
                           *(max(w, 1) for w in lay.widest), lay.pvalues, lay.pe12, lay.pab,
                           lay.pstart, lay.opair, max(lay.widest_pairs, 1))  # fmt: skip
    if loop != "query":
        raise ValueError(f"loop must be 'auto', 'grouped' or 'query', got {loop!r}")
    return _per_query_nb(*args, *(max(w, 1) for w in lay.widest))

"""The sparse sums of Eq. 5/6 over a batch of queries: NumPy, and compiled when numba is present.

Both backends take the same flat arrays (see :meth:`RuntimeBTF.arrays`) and per-query inputs:

* ``pts, i1, i2`` — data point and in-patch texel of each query;
* ``li, lw`` / ``vi, vw`` — (n, k) neighbour indices and weights for light and view;
* ``tau`` — run-time level of detail per query, (n,) float64 (:func:`prefix_weights`): the first
  ⌊τ⌋ coefficients of the point count fully and the next one with weight τ − ⌊τ⌋ (they are
  stored by decreasing magnitude, so this is a prefix, continuous in τ).

:func:`separable_sum` returns
X = Σ_s v_s U1[i1,l1] U2[i2,l2] (Σ_a wl_a U3[L_a,l3]) (Σ_b wv_b U4[V_b,l4])
(Eq. 6 with both angular modes interpolated); :func:`pair_sums` returns the un-weighted
X(L_a, V_b) for every neighbour pair, which the release's log-domain interpolation weighs
with per-pair statistics. NumPy is the reference; numba is a loop per query that skips the
padding NumPy needs for points of different coefficient counts (about 10× faster on 2 cores,
``benchmarks/bench_runtime.py``).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

__all__ = ["HAVE_NUMBA", "gather_terms", "pair_sums", "prefix_weights", "separable_sum"]

from .._numba import HAVE_NUMBA
from .._numba import numba as _nb

#: Budget of gathered entries per NumPy chunk (queries × coefficients × neighbours).
_NUMPY_BUDGET = 1 << 22


def _unpack(code: np.ndarray) -> tuple[np.ndarray, ...]:
    return code & 0xFF, (code >> 8) & 0xFF, (code >> 16) & 0xFF, code >> 24


def prefix_weights(tau: np.ndarray | float, s: np.ndarray) -> np.ndarray:
    """Weight of the coefficient at rank ``s`` (0 = largest) under a fractional level of detail
    τ: clip(τ − s, 0, 1). An integer τ keeps a prefix of τ coefficients; between integers the
    last one fades in, so the decoded value is continuous in τ (no seam where a renderer's τ
    changes across the image). Broadcasts ``tau`` against ``s``."""
    return np.clip(np.asarray(tau, dtype=np.float64) - s, 0.0, 1.0)


def gather_terms(
    values: np.ndarray,
    locations: np.ndarray,
    offsets: np.ndarray,
    membership: np.ndarray,
    dicts: Sequence[np.ndarray],
    pts: np.ndarray,
    tau: int | np.ndarray | None,
    rows: Sequence[np.ndarray],
) -> tuple[np.ndarray, list[np.ndarray]]:
    """The terms of Eq. 5 for a batch of points: the NumPy reference of every backend.

    Eq. 5 sums over each point's kept coefficients s: v_s Π_n U_n[k, row_n, l_n(s)]. Here the
    first ``tau`` (None: all; an (n,) array: per point, fractional as :func:`prefix_weights`,
    the values weighted) coefficients of every point in ``pts`` (n,) are gathered,
    padded to the widest point with zero values, together with one factor per mode:

    * ``values`` (nnz,), ``offsets`` (P+1,), ``membership`` (P,) as in :class:`SparseCodes`;
      ``locations`` (nnz, N) multi-indices, or (nnz,) uint32 packed l1 | l2<<8 | l3<<16 | l4<<24;
    * ``dicts`` — per mode (K, m_n, m_n); ``rows`` — per mode the dictionary rows wanted,
      (r_n,) for every point or (n, r_n) per point (a texel, a light's neighbours, ...).

    Returns ``val`` (n, w) float64 and per mode ``factor_n`` (n, w, r_n) = U_n[k, row, l_n].
    """
    start = offsets[pts].astype(np.int64)
    cnt = (offsets[pts + 1] - offsets[pts]).astype(np.int64)
    frac = tau is not None and np.ndim(tau) > 0
    if frac:
        cnt = np.minimum(cnt, np.ceil(tau).astype(np.int64))
    elif tau is not None:
        cnt = np.minimum(cnt, tau)
    width = int(cnt.max()) if cnt.size else 0
    col = np.arange(width)
    valid = col[None, :] < cnt[:, None]
    pos = np.where(valid, start[:, None] + col[None, :], 0)
    val = np.where(valid, values[pos], 0).astype(np.float64)
    if frac:
        val *= prefix_weights(np.asarray(tau)[:, None], col[None, :])
    loc = locations[pos]
    loc = np.stack(_unpack(loc.astype(np.int64)), axis=-1) if loc.ndim == 2 else loc
    k = membership[pts][:, None, None]
    factors = [
        d[k, np.atleast_2d(r)[:, None, :], loc[..., n, None]]
        for n, (d, r) in enumerate(zip(dicts, rows, strict=True))
    ]
    return val, factors


def _gather(ch: dict[str, np.ndarray], pts, i1, i2, li, vi, tau: np.ndarray):
    """Per-query padded coefficient data: (coef·U1·U2 (n, w), U3 rows (n, w, kl), U4 (n, w, kv))."""
    args = _args(ch)
    val, (f1, f2, g3, g4) = gather_terms(
        *args[:4], args[4:], pts, tau, [i1[:, None], i2[:, None], li, vi]
    )
    return val * f1[..., 0] * f2[..., 0], g3, g4


def _chunks(ch: dict[str, np.ndarray], pts: np.ndarray, tau: np.ndarray, k: int):
    off = ch["offsets"]
    widest = int(min(np.max(off[1:] - off[:-1], initial=1), np.ceil(np.max(tau, initial=1))))
    step = max(64, _NUMPY_BUDGET // max(widest * k, 1))
    for s in range(0, pts.size, step):
        yield slice(s, s + step)


def _separable_numpy(ch, pts, i1, i2, li, lw, vi, vw, tau) -> np.ndarray:
    out = np.empty(pts.size, dtype=np.float64)
    for sl in _chunks(ch, pts, tau, max(li.shape[1], vi.shape[1])):
        a, g3, g4 = _gather(ch, pts[sl], i1[sl], i2[sl], li[sl], vi[sl], tau[sl])
        s3 = np.einsum("nwa,na->nw", g3, lw[sl])
        s4 = np.einsum("nwb,nb->nw", g4, vw[sl])
        out[sl] = np.einsum("nw,nw,nw->n", a, s3, s4)
    return out


def _pairs_numpy(ch, pts, i1, i2, li, vi, tau) -> np.ndarray:
    out = np.empty((pts.size, li.shape[1], vi.shape[1]), dtype=np.float64)
    for sl in _chunks(ch, pts, tau, li.shape[1] * vi.shape[1]):
        a, g3, g4 = _gather(ch, pts[sl], i1[sl], i2[sl], li[sl], vi[sl], tau[sl])
        out[sl] = np.einsum("nw,nwa,nwb->nab", a, g3, g4)
    return out


if HAVE_NUMBA:

    @_nb.njit(parallel=True, cache=True, nogil=True)
    def _separable_nb(vals, locs, offs, memb, d1, d2, d3, d4, pts, i1, i2, li, lw, vi, vw, tau):
        n = pts.shape[0]
        kl = li.shape[1]
        kv = vi.shape[1]
        n_l = d3.shape[1]
        n_v = d4.shape[1]
        out = np.empty(n, dtype=np.float64)
        for q in _nb.prange(n):
            p = pts[q]
            k = memb[p]
            s0 = offs[p]
            t = tau[q]
            s1 = min(offs[p + 1], s0 + np.int64(np.ceil(t)))
            # Interpolate the two angular dictionary rows once per query (Eq. 6), then the
            # sparse sum is four loads per coefficient: 3–5× faster than weighing every term.
            r3 = np.zeros(n_l)
            r4 = np.zeros(n_v)
            for j in range(kl):
                w = lw[q, j]
                row = li[q, j]
                for m in range(n_l):
                    r3[m] += w * d3[k, row, m]
            for j in range(kv):
                w = vw[q, j]
                row = vi[q, j]
                for m in range(n_v):
                    r4[m] += w * d4[k, row, m]
            acc = 0.0
            for s in range(s0, s1):
                c = locs[s]
                acc += (
                    np.float64(vals[s])
                    * min(1.0, t - (s - s0))
                    * d1[k, i1[q], c & 0xFF]
                    * d2[k, i2[q], (c >> 8) & 0xFF]
                    * r3[(c >> 16) & 0xFF]
                    * r4[c >> 24]
                )
            out[q] = acc
        return out

    @_nb.njit(parallel=True, cache=True, nogil=True)
    def _pairs_nb(vals, locs, offs, memb, d1, d2, d3, d4, pts, i1, i2, li, vi, tau):
        n = pts.shape[0]
        kl = li.shape[1]
        kv = vi.shape[1]
        out = np.zeros((n, kl, kv), dtype=np.float64)
        for q in _nb.prange(n):
            p = pts[q]
            k = memb[p]
            s0 = offs[p]
            t = tau[q]
            s1 = min(offs[p + 1], s0 + np.int64(np.ceil(t)))
            for s in range(s0, s1):
                c = locs[s]
                l3 = (c >> 16) & 0xFF
                l4 = c >> 24
                a = (
                    np.float64(vals[s])
                    * min(1.0, t - (s - s0))
                    * d1[k, i1[q], c & 0xFF]
                    * d2[k, i2[q], (c >> 8) & 0xFF]
                )
                for ja in range(kl):
                    g = a * d3[k, li[q, ja], l3]
                    for jb in range(kv):
                        out[q, ja, jb] += g * d4[k, vi[q, jb], l4]
        return out


def _per_query(tau: float | np.ndarray, n: int) -> np.ndarray:
    """τ as an (n,) float64 array (one level broadcast to every query)."""
    return np.ascontiguousarray(np.broadcast_to(np.asarray(tau, dtype=np.float64), (n,)))


def _args(ch: dict[str, np.ndarray]) -> tuple[np.ndarray, ...]:
    return (
        ch["values"],
        ch["locations"],
        ch["offsets"],
        ch["membership"],
        ch["dict1"],
        ch["dict2"],
        ch["dict3"],
        ch["dict4"],
    )


def separable_sum(
    ch: dict[str, np.ndarray],
    pts: np.ndarray,
    i1: np.ndarray,
    i2: np.ndarray,
    li: np.ndarray,
    lw: np.ndarray,
    vi: np.ndarray,
    vw: np.ndarray,
    tau: float | np.ndarray,
    backend: str = "numpy",
) -> np.ndarray:
    """Eq. 6 for every query (float64 (n,)): one sparse sum serves all neighbour pairs.
    ``tau``: one level for every query or (n,) per query (fractional, :func:`prefix_weights`)."""
    tau = _per_query(tau, pts.size)
    if backend == "numba":
        return _separable_nb(*_args(ch), pts, i1, i2, li, lw, vi, vw, tau)
    return _separable_numpy(ch, pts, i1, i2, li, lw, vi, vw, tau)


def pair_sums(
    ch: dict[str, np.ndarray],
    pts: np.ndarray,
    i1: np.ndarray,
    i2: np.ndarray,
    li: np.ndarray,
    vi: np.ndarray,
    tau: float | np.ndarray,
    backend: str = "numpy",
) -> np.ndarray:
    """Eq. 5 at every (light neighbour, view neighbour) pair, (n, kl, kv) float64, one pass.
    ``tau`` as in :func:`separable_sum`."""
    tau = _per_query(tau, pts.size)
    if backend == "numba":
        return _pairs_nb(*_args(ch), pts, i1, i2, li, vi, tau)
    return _pairs_numpy(ch, pts, i1, i2, li, vi, tau)

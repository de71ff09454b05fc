"""The runtime's steps after the sums of Eq. 6, fused per query: de-standardisation with the
interpolated statistics, YUV → RGB, the bound, exp (the reference's NumPy steps in
:meth:`~sparsebtf.runtime.RuntimeBTF.evaluate`)."""

from __future__ import annotations

import numpy as np

from .._numba import HAVE_NUMBA
from .._numba import numba as _nb

if HAVE_NUMBA:
    from .._lanes import pow2

__all__ = ["finish"]

#: Queries per block of the finishing step (its exp runs over a block in a loop of its own).
_FINISH = 256


if HAVE_NUMBA:

    @_nb.njit(cache=True, nogil=True, inline="always", error_model="numpy")
    def _exp(x):
        # e^x within 4e-16 relative for float64 x (np.exp: a library call per value, a third
        # of the finishing step; this is plain arithmetic, so a loop of it vectorises):
        # x = k·ln2 + r with |r| <= ln2/2 (Cody-Waite, fdlibm's split of ln2), e^r by its
        # Taylor series to r^12 (remainder < 2e-16), times 2^k from exponent bits. x is
        # clamped to [-708, 709] (e^x below float64's normal range rounds to float32 0
        # anyway; above it, float32 overflows to inf the same).
        y = x if x > -708.0 else -708.0
        y = y if y < 709.0 else 709.0
        k = np.floor(y * 1.4426950408889634 + 0.5)
        r = (y - k * 6.93147180369123816490e-01) - k * 1.90821492927058770002e-10
        p = 1.0 / 479001600.0
        p = p * r + 1.0 / 39916800.0
        p = p * r + 1.0 / 3628800.0
        p = p * r + 1.0 / 362880.0
        p = p * r + 1.0 / 40320.0
        p = p * r + 1.0 / 5040.0
        p = p * r + 1.0 / 720.0
        p = p * r + 1.0 / 120.0
        p = p * r + 1.0 / 24.0
        p = p * r + 1.0 / 6.0
        p = p * r + 0.5
        p = p * r + 1.0
        p = p * r + 1.0
        e = p * pow2(np.int64(k))
        return e if x == x else x  # NaN stays NaN

    @_nb.njit(parallel=True, cache=True, nogil=True, error_model="numpy")
    def _finish_nb(x, li, lw, vi, vw, mean, std, bound, m, log_offset, bounded, rgb, order):
        # de-standardise with the interpolated statistics (Eq. 6), YUV -> RGB, the bound
        # interpolated with the same weights, exp: the reference's NumPy steps, per query,
        # a block of _FINISH queries at a time (the exp in a loop of its own, vectorised);
        # row q of the inputs answers query order[q] (none given: q).
        n = x.shape[0]
        ordered = order.shape[0] > 0
        kl = li.shape[1]
        kv = vi.shape[1]
        s = mean.shape[0]
        out = np.empty((n, 3), dtype=np.float32)
        for blk in _nb.prange((n + _FINISH - 1) // _FINISH):
            q0 = blk * _FINISH
            nb_ = min(_FINISH, n - q0)
            v = np.empty(3 * _FINISH)
            for j in range(nb_):
                q = q0 + j
                # μ and σ interpolated once per statistics channel (S = 1: shared by Y, U, V)
                mu0 = mu1 = mu2 = sd0 = sd1 = sd2 = bq = 0.0
                for a in range(kl):
                    for b in range(kv):
                        w = lw[q, a] * vw[q, b]
                        la, vb = li[q, a], vi[q, b]
                        mu0 += w * mean[0, la, vb]
                        sd0 += w * std[0, la, vb]
                        if s == 3:
                            mu1 += w * mean[1, la, vb]
                            sd1 += w * std[1, la, vb]
                            mu2 += w * mean[2, la, vb]
                            sd2 += w * std[2, la, vb]
                        if bounded:
                            bq += w * bound[la, vb]
                if s != 3:
                    mu1 = mu2 = mu0
                    sd1 = sd2 = sd0
                y = x[q, 0] * sd0 + mu0
                u = x[q, 1] * sd1 + mu1
                w_ = x[q, 2] * sd2 + mu2
                for c in range(3):
                    t = m[c, 0] * y + m[c, 1] * u + m[c, 2] * w_ if rgb else (
                        y if c == 0 else (u if c == 1 else w_))  # fmt: skip
                    if rgb and bounded:
                        t = min(t, bq)
                    v[3 * j + c] = t
            if rgb:
                for i in range(np.uint64(3 * nb_)):
                    v[i] = _exp(v[i]) - log_offset
            for j in range(nb_):
                r = order[q0 + j] if ordered else np.int64(q0 + j)
                for c in range(3):
                    out[r, c] = v[3 * j + c]
        return out


def finish(x: np.ndarray, li: np.ndarray, lw: np.ndarray, vi: np.ndarray, vw: np.ndarray,
           mean: np.ndarray, std: np.ndarray, bound: np.ndarray | None, matrix: np.ndarray,
           log_offset: float, rgb: bool, order: np.ndarray | None = None
           ) -> np.ndarray:  # fmt: skip
    """The runtime's steps after the sums, fused per query: ``x`` (n, 3) standardised Y, U, V
    sums → (n, 3) float32 linear RGB (``rgb``) or log-YUV. ``mean``/``std`` (S, L, V),
    ``bound`` (L, V) or None, ``matrix`` the (3, 3) YUV → RGB matrix; ``order`` (n,) a
    permutation: input row q is written to output row ``order[q]``."""
    b = np.zeros((1, 1)) if bound is None else bound
    o = np.empty(0, dtype=np.int64) if order is None else np.ascontiguousarray(order)
    return _finish_nb(x, li, lw, vi, vw, mean, std, b, np.ascontiguousarray(matrix),
                      float(log_offset), bound is not None, bool(rgb), o)  # fmt: skip

"""The per-value passes of the preprocessing (paper §3.1): NumPy, and compiled when numba is
present (``SPARSEBTF_NO_NUMBA=1`` keeps NumPy).

Every value of a BTF goes through the same three steps, whether a data point is coded
(:meth:`~sparsebtf.points.preprocessing.Preprocessor.forward_into`) or the statistics are
gathered (:func:`~sparsebtf.points.statistics.statistic_sums`)::

    q   = max(x, 0) + offset         clamp_offset   (counts NaN/Inf and negatives)
    l   = ln q                       NumPy's log, in place, on both paths
    yuv = M · l                      then either standardise or accumulate the sums

The compiled path touches each value three times (one pass each) instead of the six
temporaries of the NumPy expressions; the logarithm stays NumPy's (SIMD: numba's scalar log
is slower than it without Intel's SVML), so both paths take the same logarithms. The colour
transform is written out as ``M[c,0]·r + M[c,1]·g + M[c,2]·b`` in float32 on both paths; the
compiled path gives the NumPy twin's values to the last bit where the compiler keeps those
roundings, and within 2 ulp otherwise (``tests/test_preprocessing_kernels.py``).

Arrays are (n, A, 3) float32 with A angular samples (lights × views) and R, G, B (or Y, U, V)
last; μ and 1/σ are (A, 3) float32.
"""

from __future__ import annotations

import numpy as np

from .._numba import HAVE_NUMBA
from .._numba import numba as _nb

__all__ = [
    "HAVE_NUMBA",
    "accumulate_sums",
    "clamp_offset",
    "log_histogram",
    "log_offset",
    "standardise_log_rgb",
]


def _clamp_offset_numpy(x: np.ndarray, offset: np.float32, out: np.ndarray) -> tuple[int, int]:
    bad = int(x.size - np.count_nonzero(np.isfinite(x)))
    negatives = int(np.count_nonzero(x < 0))
    np.maximum(x, 0, out=out)
    out += offset
    return bad, negatives


def _standardise_numpy(
    logs: np.ndarray, m: np.ndarray, mu: np.ndarray, inv: np.ndarray
) -> None:
    r, g, b = logs[..., 0].copy(), logs[..., 1].copy(), logs[..., 2].copy()
    for c in range(3):
        y = m[c, 0] * r
        y += m[c, 1] * g
        y += m[c, 2] * b
        y -= mu[:, c]
        y *= inv[:, c]
        logs[..., c] = y


def _standardise_planar_numpy(
    logs: np.ndarray, m: np.ndarray, mu: np.ndarray, inv: np.ndarray, out: np.ndarray
) -> None:
    r, g, b = logs[..., 0], logs[..., 1], logs[..., 2]
    for c in range(3):
        y = m[c, 0] * r
        y += m[c, 1] * g
        y += m[c, 2] * b
        y -= mu[:, c]
        y *= inv[:, c]
        out[c] = y


def _yuv_numpy(logs: np.ndarray, m: np.ndarray) -> np.ndarray:
    r, g, b = logs[..., 0], logs[..., 1], logs[..., 2]
    out = np.empty_like(logs)
    for c in range(3):
        y = m[c, 0] * r
        y += m[c, 1] * g
        y += m[c, 2] * b
        out[..., c] = y
    return out


def _accumulate_numpy(
    logs: np.ndarray, m: np.ndarray, shift: np.ndarray, s1: np.ndarray, s2: np.ndarray,
    top: np.ndarray, first: bool,
) -> None:  # fmt: skip
    if not logs.shape[0]:
        return
    # max over texels first: a reduction over the leading axis runs at memory speed
    np.maximum(top, logs.max(axis=0).max(axis=-1), out=top)
    x = _yuv_numpy(logs, m)
    if first:
        shift[:] = x[0]
    x -= shift
    # NumPy reduces the leading axis texel after texel from zero, as the compiled loop does.
    s1 += x.sum(axis=0, dtype=np.float64)
    s2 += np.square(x).sum(axis=0, dtype=np.float64)


def _bins_numpy(logs: np.ndarray, low: float, per: float, counts: np.ndarray) -> None:
    b = np.floor((logs - low) * per).astype(np.int64)
    counts += np.bincount(np.clip(b, 0, counts.size - 1), minlength=counts.size)


if HAVE_NUMBA:
    assert _nb is not None

    @_nb.njit(cache=True, nogil=True)
    def _bins_nb(logs, low, per, counts):  # pragma: no cover - compiled
        top = counts.size - 1
        for i in range(logs.size):  # one pass, no temporaries of the sample
            b = np.int64(np.floor((logs[i] - low) * per))
            counts[min(max(b, 0), top)] += 1

    @_nb.njit(cache=True, nogil=True)
    def _clamp_offset_nb(x, offset, out):  # pragma: no cover - compiled
        xf = x.reshape(-1)
        of = out.reshape(-1)
        bad = 0
        negatives = 0
        zero = np.float32(0)
        for i in range(xf.size):  # branch-free, so that it vectorises (0.5 ns a value)
            v = xf[i]
            bad += np.int64(not (v - v == zero))  # NaN and ±Inf give NaN
            negatives += np.int64(v < zero)
            of[i] = max(v, zero) + offset
        return bad, negatives

    @_nb.njit(cache=True, nogil=True)
    def _standardise_nb(logs, m, mu, inv):  # pragma: no cover - compiled
        m00, m01, m02 = m[0, 0], m[0, 1], m[0, 2]
        m10, m11, m12 = m[1, 0], m[1, 1], m[1, 2]
        m20, m21, m22 = m[2, 0], m[2, 1], m[2, 2]
        for i in range(logs.shape[0]):
            for a in range(logs.shape[1]):
                r = logs[i, a, 0]
                g = logs[i, a, 1]
                b = logs[i, a, 2]
                logs[i, a, 0] = (m00 * r + m01 * g + m02 * b - mu[a, 0]) * inv[a, 0]
                logs[i, a, 1] = (m10 * r + m11 * g + m12 * b - mu[a, 1]) * inv[a, 1]
                logs[i, a, 2] = (m20 * r + m21 * g + m22 * b - mu[a, 2]) * inv[a, 2]

    @_nb.njit(cache=True, nogil=True)
    def _standardise_planar_nb(logs, m, mu, inv, out):  # pragma: no cover - compiled
        m00, m01, m02 = m[0, 0], m[0, 1], m[0, 2]
        m10, m11, m12 = m[1, 0], m[1, 1], m[1, 2]
        m20, m21, m22 = m[2, 0], m[2, 1], m[2, 2]
        for i in range(logs.shape[0]):
            for a in range(logs.shape[1]):
                r = logs[i, a, 0]
                g = logs[i, a, 1]
                b = logs[i, a, 2]
                out[0, i, a] = (m00 * r + m01 * g + m02 * b - mu[a, 0]) * inv[a, 0]
                out[1, i, a] = (m10 * r + m11 * g + m12 * b - mu[a, 1]) * inv[a, 1]
                out[2, i, a] = (m20 * r + m21 * g + m22 * b - mu[a, 2]) * inv[a, 2]

    @_nb.njit(cache=True, nogil=True)
    def _accumulate_nb(logs, m, shift, s1, s2, top, first):  # pragma: no cover - compiled
        m00, m01, m02 = m[0, 0], m[0, 1], m[0, 2]
        m10, m11, m12 = m[1, 0], m[1, 1], m[1, 2]
        m20, m21, m22 = m[2, 0], m[2, 1], m[2, 2]
        n_a = logs.shape[1]
        b1 = np.zeros(3 * n_a)
        b2 = np.zeros(3 * n_a)
        d = np.empty(3 * n_a, dtype=np.float32)
        sh = shift.reshape(-1)
        for i in range(logs.shape[0]):
            for a in range(n_a):
                r = logs[i, a, 0]
                g = logs[i, a, 1]
                b = logs[i, a, 2]
                top[a] = max(top[a], max(r, max(g, b)))
                d[3 * a] = m00 * r + m01 * g + m02 * b
                d[3 * a + 1] = m10 * r + m11 * g + m12 * b
                d[3 * a + 2] = m20 * r + m21 * g + m22 * b
            if first and i == 0:  # the first texel's Y, U, V are the shift
                sh[:] = d
            # unit stride, no branch: vectorised over the angular samples and channels; each
            # sum still runs texel after texel, as the NumPy twin's
            for j in range(3 * n_a):
                e = d[j] - sh[j]
                b1[j] += e
                b2[j] += e * e
        s1 += b1.reshape(n_a, 3)
        s2 += b2.reshape(n_a, 3)


def _backend(backend: str | None) -> str:
    return backend or ("numba" if HAVE_NUMBA else "numpy")


def clamp_offset(
    x: np.ndarray, offset: float, out: np.ndarray, backend: str | None = None
) -> tuple[int, int]:
    """``out = max(x, 0) + offset`` (float32, any shape equal to x's); returns (NaN/Inf count,
    negative count) of ``x``. NaN stays NaN in ``out`` (callers refuse it)."""
    e = np.float32(offset)
    if _backend(backend) == "numba":
        bad, negatives = _clamp_offset_nb(x, e, out)
        return int(bad), int(negatives)
    return _clamp_offset_numpy(x, e, out)


def log_offset(
    x: np.ndarray, offset: float, out: np.ndarray | None = None, backend: str | None = None
) -> tuple[np.ndarray, int, int]:
    """``ln(max(x, 0) + offset)`` in float32 into ``out`` (new if None): (logs, NaN/Inf count,
    negative count). The log is NumPy's on every backend."""
    x = np.ascontiguousarray(x, dtype=np.float32)
    out = np.empty_like(x) if out is None else out
    bad, negatives = clamp_offset(x, offset, out, backend)
    with np.errstate(invalid="ignore"):
        np.log(out, out=out)
    return out, bad, negatives


def standardise_log_rgb(
    logs: np.ndarray, m: np.ndarray, mu: np.ndarray, inv: np.ndarray, backend: str | None = None,
    out: np.ndarray | None = None,
) -> np.ndarray:  # fmt: skip
    """``(M · l − μ) · (1/σ)`` per angular sample of (n, A, 3) float32 log-RGB: in place, or
    with ``out`` (3, n, A) float32 channel by channel there (planar: a channel of a batch is
    then one contiguous array, no copy of it per channel; same values)."""
    numba = _backend(backend) == "numba"
    if out is None:
        (_standardise_nb if numba else _standardise_numpy)(logs, m, mu, inv)
        return logs
    (_standardise_planar_nb if numba else _standardise_planar_numpy)(logs, m, mu, inv, out)
    return out


def log_histogram(
    x: np.ndarray, low: float, per: float, counts: np.ndarray, backend: str | None = None
) -> None:
    """Add the positive values of ``x`` to ``counts`` (int64, n bins): bin
    ⌊per·(log10 x − low)⌋ clipped to [0, n − 1], the logarithm NumPy's in float64 on every
    backend (the compiled path bins without the NumPy path's four temporaries)."""
    v = x.ravel()
    logs = np.log10(v[v > 0], dtype=np.float64)
    if _backend(backend) == "numba":
        _bins_nb(logs, float(low), float(per), counts)
    else:
        _bins_numpy(logs, low, per, counts)


def accumulate_sums(
    logs: np.ndarray, m: np.ndarray, shift: np.ndarray, s1: np.ndarray, s2: np.ndarray,
    top: np.ndarray, first: bool, backend: str | None = None,
) -> None:  # fmt: skip
    """Add texels ``logs`` (n, A, 3) float32 log-RGB to the sums of their angular samples.

    With y = M · l in float32 and d = y − shift (float32): ``s1 += Σd`` and ``s2 += Σd²``
    (d² in float32, each sum in float64 texel after texel from zero);
    ``top = max(top, max over R, G, B of l)`` (A,) float64. ``first``: ``shift`` (A, 3)
    float32 is set to the first texel's y (it keeps Σd² accurate).
    """
    if _backend(backend) == "numba":
        _accumulate_nb(logs, m, shift, s1, s2, top, first)
    else:
        _accumulate_numpy(logs, m, shift, s1, s2, top, first)

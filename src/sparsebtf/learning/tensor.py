"""Tensor algebra named after the maths (TensorLy conventions): unfold, fold, mode_dot.

``mode_dot(X, U, n)`` is the n-mode product X ×_n U of the paper's Notation: every mode-n
fibre of X is multiplied by U (shape (J, m_n)). :func:`project` and :func:`reconstruct` apply
one matrix per mode to a *batch* of data points with one BLAS call per mode (a single GEMM for
the last mode, batched GEMMs for the others), never a Python loop over elements.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

__all__ = [
    "fold",
    "mode_dot",
    "multi_mode_dot",
    "project",
    "project_into",
    "project_modes",
    "projection_order",
    "reconstruct",
    "reconstruct_sparse",
    "sum_squares",
    "unfold",
]


def unfold(tensor: np.ndarray, mode: int) -> np.ndarray:
    """Mode-n unfolding: (m_n, ∏ other sizes), fibres as columns (TensorLy ordering)."""
    return np.moveaxis(tensor, mode, 0).reshape(tensor.shape[mode], -1)


def fold(matrix: np.ndarray, mode: int, shape: Sequence[int]) -> np.ndarray:
    """Inverse of :func:`unfold` for a tensor of the given full shape."""
    full = [shape[mode], *(s for i, s in enumerate(shape) if i != mode)]
    return np.moveaxis(matrix.reshape(full), 0, mode)


def _apply(x: np.ndarray, m: np.ndarray, axis: int) -> np.ndarray:
    """Contract ``axis`` of x with m's second index: out[.., j, ..] = Σ_i m[j, i] x[.., i, ..]."""
    if axis == x.ndim - 1 or axis == -1:
        mt = np.ascontiguousarray(m.T)
        if x.ndim >= 2:
            # Stacked (m_{N-1} × m_N) GEMMs run faster in OpenBLAS than one tall, thin GEMM
            # with a 151-wide inner dimension (measured: 11.2 vs 13.6 ms per data point).
            rows = x.shape[-2]
            return (x.reshape(-1, rows, x.shape[-1]) @ mt).reshape(*x.shape[:-1], m.shape[0])
        return x @ mt
    shape = x.shape
    pre = int(np.prod(shape[:axis], dtype=np.int64))
    post = int(np.prod(shape[axis + 1 :], dtype=np.int64))
    # A contiguous left operand keeps numpy's stacked matmul on BLAS GEMM.
    out = np.matmul(np.ascontiguousarray(m), x.reshape(pre, shape[axis], post))
    return out.reshape(*shape[:axis], m.shape[0], *shape[axis + 1 :])


def mode_dot(tensor: np.ndarray, matrix: np.ndarray, mode: int) -> np.ndarray:
    """n-mode product X ×_n U, U of shape (J, m_n)."""
    if matrix.ndim != 2 or matrix.shape[1] != tensor.shape[mode]:
        raise ValueError(
            f"mode_dot: matrix {matrix.shape} does not fit mode {mode} of size {tensor.shape[mode]}"
        )
    return _apply(np.ascontiguousarray(tensor), matrix, mode)


def multi_mode_dot(
    tensor: np.ndarray,
    matrices: Sequence[np.ndarray],
    modes: Sequence[int] | None = None,
    transpose: bool = False,
) -> np.ndarray:
    """X ×_1 U1 ×_2 U2 … (or with every Uᵀ when ``transpose``)."""
    modes = range(len(matrices)) if modes is None else modes
    out = tensor
    for m, mode in zip(matrices, modes, strict=True):
        out = mode_dot(out, m.T if transpose else m, mode)
    return out


def project(
    batch: np.ndarray, matrices: Sequence[np.ndarray], skip: int | None = None
) -> np.ndarray:
    """Eq. 3 on a batch: S_b = X_b ×_1 U1ᵀ ×_2 U2ᵀ … for data points X_b = batch[b].

    ``batch`` has shape (B, m_1, …, m_N); ``matrices`` are the N orthonormal (m_n, m_n) bases.
    With ``skip = n`` mode n is left out (the partial projection used by the Procrustes update).
    """
    modes = [n for n in projection_order([m.shape[0] for m in matrices]) if n != skip]
    return project_modes(batch, matrices, modes)


def projection_order(mode_sizes: Sequence[int]) -> list[int]:
    """The order :func:`project` applies the modes in: largest first (ties: lower mode first).

    The big angular modes go first while the tensor is still contiguous from the caller; the
    last two (the small spatial modes) leave intermediates the training step reuses.
    """
    return sorted(range(len(mode_sizes)), key=lambda n: -int(mode_sizes[n]))


def project_modes(
    batch: np.ndarray, matrices: Sequence[np.ndarray], modes: Sequence[int]
) -> np.ndarray:
    """X_b ×_n U_nᵀ for the listed modes only, in the listed order (batch (B, m_1, …, m_N)).

    With all modes in :func:`projection_order` this is :func:`project`; a prefix of that order
    is the intermediate :func:`project` passes through (same arithmetic, same rounding).
    """
    out = np.ascontiguousarray(batch)
    for n in modes:
        # X ×_n Uᵀ contracts with U's rows: apply Uᵀ.
        out = _apply(out, matrices[n].T, n + 1)
    return out


def project_into(
    batch: np.ndarray, matrices: Sequence[np.ndarray], buffers: list[np.ndarray]
) -> np.ndarray:
    """:func:`project` with every intermediate written into ``buffers`` (two flat float arrays
    of at least the batch's size, in its dtype, reused from call to call): the same GEMMs in
    the same order on the same operands, so the same values bit for bit, without a fresh
    array per mode (9 MB each at 10×10×151×151), whose pages the allocator may have to map
    and zero again (``benchmarks/bench_encode_real.py --ab`` compares both; under load the
    difference was within the noise). Returns a view of one buffer: read it before the next
    call."""
    out = np.ascontiguousarray(batch)
    size = out.size
    for i, n in enumerate(projection_order([m.shape[0] for m in matrices])):
        m = matrices[n].T  # X ×_n Uᵀ contracts with U's rows: apply Uᵀ
        axis = n + 1
        dest = buffers[i % 2][:size]
        shape = out.shape
        if axis == out.ndim - 1:
            rows = shape[-2]
            np.matmul(out.reshape(-1, rows, shape[-1]), np.ascontiguousarray(m.T),
                      out=dest.reshape(-1, rows, m.shape[0]))  # fmt: skip
        else:
            pre = int(np.prod(shape[:axis], dtype=np.int64))
            post = int(np.prod(shape[axis + 1 :], dtype=np.int64))
            np.matmul(np.ascontiguousarray(m), out.reshape(pre, shape[axis], post),
                      out=dest.reshape(pre, m.shape[0], post))  # fmt: skip
        out = dest.reshape(*shape[:axis], m.shape[0], *shape[axis + 1 :])
    return out


def reconstruct(coeffs: np.ndarray, matrices: Sequence[np.ndarray]) -> np.ndarray:
    """Eq. 4 on a batch: X_b = S_b ×_1 U1 ×_2 U2 … (coeffs of shape (B, m_1, …, m_N))."""
    out = np.ascontiguousarray(coeffs)
    for n, m in enumerate(matrices):
        out = _apply(out, m, n + 1)
    return out


def reconstruct_sparse(
    locations: np.ndarray, values: np.ndarray, matrices: Sequence[np.ndarray]
) -> np.ndarray:
    """Eq. 4 from τ coefficients: X = Σ_s v_s U_1[:, l_1(s)] ∘ U_2[:, l_2(s)] ∘ … ∘ U_N[:, l_N(s)].

    ``locations`` (τ, N) and ``values`` (τ,) are the coefficients; ``matrices`` the N bases,
    possibly restricted to some rows (U_n of shape (r_n, m_n)); the result is (r_1, …, r_N).
    Only the columns A_n = {l_n(s)} the coefficients use take part: X = C ×_1 U_1[:, A_1] …
    ×_N U_N[:, A_N] with C the |A_1|×…×|A_N| core holding the values, expanded mode by mode,
    the least-growing first. Trained codes use few angular columns (about 12 and 37 of 151 at
    τ = 885), so this is a few percent of the dense 2·L·Σm_n; it never exceeds it.
    """
    loc = np.asarray(locations, dtype=np.int64)
    n = len(matrices)
    if loc.shape[0] == 0:
        return np.zeros([m.shape[0] for m in matrices], dtype=np.result_type(values, *matrices))
    cols, pos = zip(*(np.unique(loc[:, q], return_inverse=True) for q in range(n)), strict=True)
    core = np.zeros([c.size for c in cols], dtype=np.result_type(values, *matrices))
    core[pos] = values
    sub = [matrices[q][:, cols[q]] for q in range(n)]
    out = core[None]
    for q in sorted(range(n), key=lambda q: sub[q].shape[0] / max(1, sub[q].shape[1])):
        out = _apply(out, sub[q], q + 1)
    return out[0]


def sum_squares(rows: np.ndarray, chunk: int = 1 << 15) -> np.ndarray:
    """(B,) float64 Σ x² of each row of a (B, n) array.

    BLAS dot products on chunks of ``chunk`` entries, summed in float64: five times faster
    than a float64 einsum on float32 data and as accurate for a Parseval difference (each
    chunk's float32 sum carries ~1e-7 relative error, far below the coding errors). The
    whole chunks of a row go to BLAS in one batched call, which lets go of the GIL once per
    row, not once per chunk: with a reader thread running beside it, 70 calls per data point
    waited for the GIL in turn.
    """
    out = np.empty(rows.shape[0])
    for i, r in enumerate(rows):
        m = r.size // chunk * chunk
        head = r[:m].reshape(-1, chunk)
        whole = np.matmul(head[:, None, :], head[:, :, None]).sum(dtype=np.float64)
        out[i] = float(whole) + float(np.dot(r[m:], r[m:]))
    return out

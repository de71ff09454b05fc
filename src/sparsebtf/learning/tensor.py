"""Tensor algebra named after the maths (TensorLy conventions): unfold, fold, mode_dot.

``mode_dot(X, U, n)`` is the n-mode product X ×_n U of the paper's Notation: every mode-n
fibre of X is multiplied by U (shape (J, m_n)). :func:`project` and :func:`reconstruct` apply
one matrix per mode to a *batch* of data points with one BLAS call per mode (a single GEMM for
the last mode, batched GEMMs for the others), never a Python loop over elements.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

__all__ = ["fold", "mode_dot", "multi_mode_dot", "project", "reconstruct", "unfold"]


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
    The big angular modes go first while the tensor is still contiguous from the caller.
    """
    out = np.ascontiguousarray(batch)
    order = sorted(range(len(matrices)), key=lambda n: -matrices[n].shape[0])
    for n in order:
        if n == skip:
            continue
        # X ×_n Uᵀ contracts with U's rows: apply Uᵀ.
        out = _apply(out, matrices[n].T, n + 1)
    return out


def reconstruct(coeffs: np.ndarray, matrices: Sequence[np.ndarray]) -> np.ndarray:
    """Eq. 4 on a batch: X_b = S_b ×_1 U1 ×_2 U2 … (coeffs of shape (B, m_1, …, m_N))."""
    out = np.ascontiguousarray(coeffs)
    for n, m in enumerate(matrices):
        out = _apply(out, m, n + 1)
    return out

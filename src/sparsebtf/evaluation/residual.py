"""Where a coded material's linear error lives, and what a per-material residual would buy
(issue 46): the share of the linear-RGB squared error in the highlights (reference values
above a threshold, 1 by default), and low-rank linear factorisations of the residual
(decoded − reference) with binary16 factors, counted in bytes as the PCA baseline counts its
factors (:func:`~sparsebtf.evaluation.baselines.pca_bytes`).

``benchmarks/bench_glossy_residual.py`` runs them on a coded glossy capture.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ..errors import BTFInputError

__all__ = [
    "LAYOUTS",
    "LowRank",
    "error_split",
    "gram_spectrum",
    "low_rank",
    "low_rank_bytes",
    "low_rank_curve",
    "residual_matrix",
    "sparse_values_curve",
    "unflatten_residual",
]

#: arrangements of a (H, W, L, V, 3) residual as a matrix: one row per texel and a column per
#: (light, view, channel) ("texels"), or one row per (light, view) and a column per (texel,
#: channel) ("directions")
LAYOUTS = ("texels", "directions")
#: bytes of one stored value of a sparse correction: binary16 value + 32-bit location
SPARSE_VALUE_BYTES = 6


def error_split(dec: np.ndarray, ref: np.ndarray, threshold: float = 1.0) -> dict[str, float]:
    """Linear MSE of ``dec`` against ``ref`` over every value, and how it splits between the
    values whose reference is above ``threshold`` ("highlights") and the others: each part's
    share of the squared error, its MSE over its own values and its share of the values."""
    if dec.shape != ref.shape:
        raise BTFInputError(f"shapes differ: {dec.shape} and {ref.shape}")
    hi = ref > threshold
    n = ref.size
    n_hi = int(hi.sum())
    sq = np.square(dec.astype(np.float64, copy=False) - ref)
    total = float(sq.sum())
    above = float(sq[hi].sum())
    below = total - above
    return {
        "mse": total / n,
        "share_above": above / total if total > 0 else 0.0,
        "mse_above": above / n_hi if n_hi else 0.0,
        "mse_below": below / (n - n_hi) if n > n_hi else 0.0,
        "values_above": n_hi / n,
        "sse_above": above,
        "sse_below": below,
    }


def residual_matrix(res: np.ndarray, layout: str) -> np.ndarray:
    """The (H, W, L, V, C) residual ``res`` as a 2D matrix of ``layout`` (:data:`LAYOUTS`)."""
    if res.ndim != 5:
        raise BTFInputError(f"a residual is (H, W, L, V, C), got shape {res.shape}")
    h, w, nl, nv, c = res.shape
    if layout == "texels":
        return res.reshape(h * w, nl * nv * c)
    if layout == "directions":
        return np.ascontiguousarray(res.transpose(2, 3, 0, 1, 4)).reshape(nl * nv, h * w * c)
    raise BTFInputError(f"layout must be one of {LAYOUTS}, got {layout!r}")


def unflatten_residual(m: np.ndarray, shape: tuple[int, ...], layout: str) -> np.ndarray:
    """Undo :func:`residual_matrix`: the matrix ``m`` back as a (H, W, L, V, C) array."""
    h, w, nl, nv, c = shape
    if layout == "texels":
        return m.reshape(shape)
    if layout == "directions":
        return m.reshape(nl, nv, h, w, c).transpose(2, 3, 0, 1, 4)
    raise BTFInputError(f"layout must be one of {LAYOUTS}, got {layout!r}")


def low_rank_bytes(rank: int, rows: int, cols: int, value_bytes: int = 2) -> int:
    """Bytes of rank-``rank`` factors of a rows × cols matrix: rank · (rows + cols) values."""
    return int(rank) * (int(rows) + int(cols)) * int(value_bytes)


@dataclass
class LowRank:
    """Leading singular triplets of a matrix M ≈ U · diag(s) · Vᵀ, and its squared norm."""

    u: np.ndarray  # (rows, r)
    s: np.ndarray  # (r,)
    vt: np.ndarray  # (r, cols)
    energy: float  # ||M||_F²

    def factors16(self, rank: int) -> tuple[np.ndarray, np.ndarray]:
        """The rank-``rank`` factors as stored: U·√s and √s·Vᵀ rounded to binary16 (as the
        PCA baseline splits them), back as float32."""
        root = np.sqrt(self.s[:rank])
        left = (self.u[:, :rank] * root).astype(np.float16).astype(np.float32)
        right = (root[:, None] * self.vt[:rank]).astype(np.float16).astype(np.float32)
        return left, right


def low_rank(m: np.ndarray, rank: int, *, oversample: int = 10, power_iters: int = 3,
             seed: int = 0) -> LowRank:  # fmt: skip
    """Top ``rank`` singular triplets of ``m`` by a randomised range finder (Halko et al.:
    a Gaussian sketch of width rank + oversample, ``power_iters`` re-orthonormalised power
    iterations); exact (to rounding) when the sketch spans the smaller side."""
    if m.ndim != 2 or rank < 1:
        raise BTFInputError(f"need a matrix and rank >= 1, got {m.shape} and {rank}")
    rows, cols = m.shape
    k = min(rank + oversample, rows, cols)
    a = np.asarray(m, dtype=np.float32)
    energy = float(np.einsum("ij,ij->", a, a, dtype=np.float64))
    if k == min(rows, cols):  # the sketch spans the smaller side: a direct SVD
        u, s, vt = np.linalg.svd(a.astype(np.float64), full_matrices=False)
    else:
        rng = np.random.default_rng(seed)
        q, _ = np.linalg.qr((a @ rng.standard_normal((cols, k)).astype(np.float32))
                            .astype(np.float64))  # fmt: skip
        for _ in range(power_iters):
            z, _ = np.linalg.qr((q.T.astype(np.float32) @ a).T.astype(np.float64))
            q, _ = np.linalg.qr((a @ z.astype(np.float32)).astype(np.float64))
        b = (q.T.astype(np.float32) @ a).astype(np.float64)  # (k, cols)
        ub, s, vt = np.linalg.svd(b, full_matrices=False)
        u = q @ ub
    r = min(rank, len(s))
    return LowRank(u[:, :r].astype(np.float32), s[:r].copy(), vt[:r].astype(np.float32),
                   energy)  # fmt: skip


def gram_spectrum(m: np.ndarray, chunk: int = 4096) -> np.ndarray:
    """Every squared singular value of ``m``, largest first: the eigenvalues of the Gram
    matrix of its smaller side, accumulated in float64 over blocks of ``chunk`` of the larger
    (exact to rounding; a check of :func:`low_rank`'s sketch)."""
    a = m if m.shape[0] <= m.shape[1] else m.T
    g = np.zeros((a.shape[0], a.shape[0]))
    for j in range(0, a.shape[1], chunk):
        b = np.asarray(a[:, j : j + chunk], dtype=np.float64)
        g += b @ b.T
    return np.clip(np.linalg.eigvalsh(g)[::-1], 0, None)


def low_rank_curve(m: np.ndarray, ranks: list[int] | tuple[int, ...], **keywords: Any
                   ) -> tuple[LowRank, list[dict[str, float]]]:  # fmt: skip
    """For each r of ``ranks``: the share of ||m||² a rank-r factorisation removes (ideal,
    Σ_{i<r} s_i² / ||m||²), the squared error left with its binary16 factors (measured) and
    their bytes (:func:`low_rank_bytes`). The factorisation is returned beside."""
    fit = low_rank(m, max(ranks), **keywords)
    rows, cols = m.shape
    out = []
    for r in ranks:
        r_eff = min(r, len(fit.s))
        left, right = fit.factors16(r_eff)
        left_err = float(np.square(m - left @ right, dtype=np.float64).sum())
        out.append({
            "rank": int(r), "removed_ideal": float((fit.s[:r_eff] ** 2).sum() / fit.energy)
            if fit.energy > 0 else 0.0,
            "sse_left": left_err, "bytes": low_rank_bytes(r, rows, cols),
        })  # fmt: skip
    return fit, out


def sparse_values_curve(
    res: np.ndarray, budgets: list[int], value_bytes: int = SPARSE_VALUE_BYTES
) -> list[dict[str, float]]:
    """A sparse correction of the residual: at each byte budget, the n = budget // value_bytes
    largest |res| values stored exactly (value and location; binary16 rounding ignored): the
    squared error left and n."""
    sq = np.square(res.ravel(), dtype=np.float64)
    total = float(sq.sum())
    n_max = min(max(int(b) // value_bytes for b in budgets), sq.size)
    top = np.sort(np.partition(sq, sq.size - n_max)[sq.size - n_max:])[::-1] if n_max else sq[:0]
    cum = np.concatenate([[0.0], np.cumsum(top)])
    out = []
    for b in budgets:
        n = min(int(b) // value_bytes, sq.size)
        out.append({"bytes": int(b), "values": n, "sse_left": max(total - float(cum[n]), 0.0)})
    return out

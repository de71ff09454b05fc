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
    "allocate_channel_ranks",
    "channels_correction",
    "error_split",
    "gram_spectrum",
    "low_rank",
    "low_rank_bytes",
    "low_rank_channels",
    "low_rank_curve",
    "residual_matrix",
    "sparse_values_curve",
    "unflatten_residual",
]

#: arrangements of a (H, W, L, V, 3) residual as a matrix: one row per texel and a column per
#: (light, view, channel) ("texels"), or one row per (light, view) and a column per (texel,
#: channel) ("directions"); "channels": a texels × (light, view) matrix per channel, the
#: total rank shared by singular value as the PCA baseline shares it
#: (:func:`low_rank_channels`)
LAYOUTS = ("texels", "directions", "channels")
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
    """The (H, W, L, V, C) residual ``res`` as a 2D matrix of ``layout`` ("texels" or
    "directions")."""
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


def allocate_channel_ranks(fits: list[LowRank], total: int) -> tuple[int, ...]:
    """Split ``total`` rank over the channels' factorisations greedily by σ² (largest
    energy first), as :func:`~sparsebtf.evaluation.baselines.allocate_ranks` does."""
    sq = np.concatenate([f.s**2 for f in fits])
    owner = np.concatenate([np.full(len(f.s), c) for c, f in enumerate(fits)])
    order = np.argsort(-sq, kind="stable")[: max(int(total), 0)]
    return tuple(int(x) for x in np.bincount(owner[order], minlength=len(fits)))


def channels_correction(fits: list[LowRank], ranks: tuple[int, ...],
                        shape: tuple[int, ...]) -> np.ndarray:  # fmt: skip
    """The (H, W, L, V, C) correction of per-channel factors of ``ranks`` (binary16)."""
    h, w, nl, nv, _ = shape
    out = np.zeros(shape, dtype=np.float32)
    for ch, (fit, r) in enumerate(zip(fits, ranks, strict=True)):
        if r:
            left, right = fit.factors16(r)
            out[..., ch] = (left @ right).reshape(h, w, nl, nv)
    return out


def low_rank_channels(res: np.ndarray, ranks: list[int] | tuple[int, ...], **keywords: Any
                      ) -> tuple[list[LowRank], list[dict[str, Any]]]:  # fmt: skip
    """The "channels" layout: per channel of the (H, W, L, V, C) ``res`` a texels × (lights ·
    views) factorisation; for each total rank R of ``ranks`` the split over the channels by
    σ² (:func:`allocate_channel_ranks`), the share of ||res||² it removes (ideal), the squared
    error left with binary16 factors (measured) and the bytes R · (texels + lights · views) · 2
    (:func:`~sparsebtf.evaluation.baselines.pca_bytes`'s count)."""
    h, w, nl, nv, c = res.shape
    top = max(ranks)
    fits = [low_rank(res[..., ch].reshape(h * w, nl * nv), top, **keywords) for ch in range(c)]
    energy = sum(f.energy for f in fits)
    out = []
    for total in ranks:
        split = allocate_channel_ranks(fits, total)
        kept = sum(float((f.s[:r] ** 2).sum()) for f, r in zip(fits, split, strict=True))
        left = float(np.square(res - channels_correction(fits, split, res.shape),
                               dtype=np.float64).sum())  # fmt: skip
        out.append({"rank": int(total), "ranks": list(split),
                    "removed_ideal": kept / energy if energy > 0 else 0.0, "sse_left": left,
                    "bytes": low_rank_bytes(total, h * w, nl * nv)})  # fmt: skip
    return fits, out

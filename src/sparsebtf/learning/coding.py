"""Sparse coding of data points on an ensemble of orthonormal dictionaries (paper §3.3).

For a data point X and each dictionary k, the projection S_k = X ×_1 U1ᵀ … ×_N UNᵀ (Eq. 3) is
exact, so by Parseval the error of keeping a subset T of its entries is ‖X‖² − Σ_{t∈T} s_t²,
with no reconstruction. Coefficients are added by decreasing magnitude until the mean squared
residual (per tensor entry) is <= ε or the count reaches τ (the release's rule, see
``official-release-format.md`` §3 step 4). The **sparsest** dictionary wins; ties and the case
where every dictionary hits the cap go to the **least error**. A point whose energy is already
below ε keeps one coefficient, as in the release.

The same function codes training batches (τ = τ_l, ε = 0: every dictionary is capped, so the
membership is the least-error one, Eq. 2).

:class:`SparseCodes` stores the result: per point its dictionary (membership m), its count
(z), and its values and multi-index locations **sorted by decreasing magnitude**, so a renderer
can truncate τ by reading a prefix.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ..errors import BTFInputError
from .parallel import parallel_map
from .tensor import project, reconstruct_sparse, sum_squares

__all__ = ["SparseCodes", "reconstruct_points", "sparse_code", "sparse_code_levels", "topk_abs"]


def topk_abs(c: np.ndarray, k: int) -> np.ndarray:
    """Indices of the ``k`` largest |c| of a 1D array, by decreasing magnitude (ties: lower index).

    Not a full sort of 2.28 M entries: the k-th largest of the maxima of 4k blocks is a lower
    bound of the k-th largest entry (k block maxima are above it), so only the entries above it
    are candidates. This keeps the selection at memory speed.
    """
    n = c.size
    k = min(k, n)
    a = np.abs(c)
    if k <= 0:
        return np.empty(0, dtype=np.int64)
    nb = 4 * k
    if n >= 8 * nb:
        bs = n // nb
        maxima = a[: nb * bs].reshape(nb, bs).max(axis=1)
        thr = np.partition(maxima, nb - k)[nb - k]
        cand = np.flatnonzero(a >= thr)
    else:
        cand = np.arange(n)
    if cand.size > k:
        ca = a[cand]
        # Stable: partition at k, keep every candidate tied with the k-th for the index order.
        kth = np.partition(ca, cand.size - k)[cand.size - k]
        cand = cand[ca >= kth]
    order = np.lexsort((cand, -a[cand]))
    return cand[order[:k]]


@dataclass(eq=False)
class SparseCodes:
    """Sparse coefficients of P data points on one ensemble.

    Attributes
    ----------
    mode_sizes : (m_1, …, m_N), the data-point tensor shape.
    membership : (P,) dictionary index of each point (m).
    counts : (P,) number of kept coefficients of each point (z).
    values : (Σ counts,) coefficient values, point after point, each point's by decreasing |v|.
    locations : (Σ counts, N) multi-indices (l_1, …, l_N) of the values.
    errors : (P,) mean squared residual per tensor entry (Parseval), in the coded domain.
    """

    mode_sizes: tuple[int, ...]
    membership: np.ndarray
    counts: np.ndarray
    values: np.ndarray
    locations: np.ndarray
    errors: np.ndarray

    def __post_init__(self) -> None:
        p = self.membership.shape[0]
        if self.counts.shape != (p,) or self.errors.shape != (p,):
            raise BTFInputError("membership, counts and errors must have one entry per point")
        n = int(self.counts.sum())
        if self.values.shape != (n,) or self.locations.shape != (n, len(self.mode_sizes)):
            raise BTFInputError(
                f"{n} coefficients announced by counts, but values {self.values.shape} and "
                f"locations {self.locations.shape}"
            )

    @property
    def n_points(self) -> int:
        return int(self.membership.shape[0])

    @property
    def nnz(self) -> int:
        return int(self.values.shape[0])

    @property
    def offsets(self) -> np.ndarray:
        """(P + 1,) start of each point's coefficients."""
        return np.concatenate([[0], np.cumsum(self.counts, dtype=np.int64)])

    def point(self, i: int) -> tuple[np.ndarray, np.ndarray]:
        """(locations (n, N), values (n,)) of point ``i``."""
        o = self.offsets
        return self.locations[o[i] : o[i + 1]], self.values[o[i] : o[i + 1]]

    def dense(self, i: int) -> np.ndarray:
        """The coefficient tensor Ŝ of point ``i`` (mostly zeros)."""
        loc, val = self.point(i)
        s = np.zeros(self.mode_sizes, dtype=np.float64)
        s[tuple(loc.T)] = val
        return s

    def truncate(self, tau: int) -> SparseCodes:
        """Keep the ``tau`` largest coefficients of every point (a prefix, since they are sorted).

        Errors are updated by Parseval: the dropped energy is added back.
        """
        if tau < 1:
            raise BTFInputError(f"truncation needs tau >= 1, got {tau}")
        o = self.offsets
        new_counts = np.minimum(self.counts, tau)
        keep = (
            np.concatenate([np.arange(o[i], o[i] + new_counts[i]) for i in range(self.n_points)])
            if self.n_points
            else np.empty(0, dtype=np.int64)
        )
        dropped = np.zeros(self.n_points)
        mask = np.ones(self.nnz, dtype=bool)
        mask[keep] = False
        owner = np.repeat(np.arange(self.n_points), self.counts)
        np.add.at(dropped, owner[mask], self.values[mask].astype(np.float64) ** 2)
        size = float(np.prod(self.mode_sizes))
        return SparseCodes(
            self.mode_sizes,
            self.membership.copy(),
            new_counts,
            self.values[keep],
            self.locations[keep],
            self.errors + dropped / size,
        )

    @staticmethod
    def concatenate(parts: Sequence[SparseCodes]) -> SparseCodes:
        """Join codes of consecutive point ranges."""
        if not parts:
            raise BTFInputError("nothing to concatenate")
        shape = parts[0].mode_sizes
        if any(p.mode_sizes != shape for p in parts):
            raise BTFInputError("cannot concatenate codes of different data-point shapes")
        return SparseCodes(
            shape,
            np.concatenate([p.membership for p in parts]),
            np.concatenate([p.counts for p in parts]),
            np.concatenate([p.values for p in parts]),
            np.concatenate([p.locations for p in parts]),
            np.concatenate([p.errors for p in parts]),
        )


def _count_and_error(
    sq_sorted: np.ndarray, energy: float, size: int, tau: int, eps: float
) -> tuple[int, float]:
    """The release's count rule on squared coefficients sorted by decreasing magnitude."""
    if energy / size < eps:
        return 1, eps
    resid = (energy - np.cumsum(sq_sorted[:tau])) / size
    hit = np.flatnonzero(resid <= eps)
    n = int(hit[0]) + 1 if hit.size else min(tau, sq_sorted.size)
    return n, float(max(resid[n - 1], 0.0))


def sparse_code(
    batch: np.ndarray,
    dictionaries: Sequence[np.ndarray],
    tau: int,
    eps: float = 0.0,
    dtype: type = np.float32,
) -> SparseCodes:
    """Code a batch of data points on an ensemble (Eq. 3 + the §3.3 selection rule).

    Parameters
    ----------
    batch : (B, m_1, …, m_N) data points.
    dictionaries : one array per mode, (K, m_n, m_n), orthonormal.
    tau : the sparsity cap τ (clipped to the tensor size).
    eps : error threshold ε on the mean squared residual per entry (0: always use τ).
    dtype : arithmetic of the projections (float32 is ~2× faster; energies stay float64).
    """
    return sparse_code_levels(batch, dictionaries, [tau], eps, dtype)[0]


def sparse_code_levels(
    batch: np.ndarray,
    dictionaries: Sequence[np.ndarray],
    taus: Sequence[int],
    eps: float = 0.0,
    dtype: type = np.float32,
) -> list[SparseCodes]:
    """:func:`sparse_code` at several caps τ from one projection per (point, dictionary).

    The projections do not depend on τ, so a quality–storage curve costs one encoding.
    Returns one :class:`SparseCodes` per τ, identical to separate :func:`sparse_code` calls.
    """
    x = np.asarray(batch)
    shape = tuple(int(s) for s in x.shape[1:])
    if len(dictionaries) != len(shape):
        raise BTFInputError(
            f"data points have {len(shape)} modes but the ensemble has {len(dictionaries)}"
        )
    for n, (d, m) in enumerate(zip(dictionaries, shape, strict=True)):
        if d.ndim != 3 or d.shape[1:] != (m, m):
            raise BTFInputError(f"mode {n + 1}: dictionaries {d.shape} do not fit mode size {m}")
    if not taus or min(taus) < 1:
        raise BTFInputError(f"sparsity tau must be >= 1, got {list(taus)}")
    n_dict = dictionaries[0].shape[0]
    size = int(np.prod(shape))
    levels = [min(int(t), size) for t in taus]
    tmax = max(levels)
    b = x.shape[0]
    nl = len(levels)
    xc = np.ascontiguousarray(x, dtype=dtype)
    energy = sum_squares(xc.reshape(b, -1))

    counts = np.empty((nl, b, n_dict), dtype=np.int64)
    errs = np.empty((nl, b, n_dict))
    best: list[list[tuple[tuple[int, float], np.ndarray, np.ndarray] | None]] = [
        [None] * b for _ in range(nl)
    ]
    mats_k = [[np.asarray(d[k], dtype=dtype) for d in dictionaries] for k in range(n_dict)]

    def task(ik: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
        i, k = ik
        s = project(xc[i : i + 1], mats_k[k]).reshape(-1)
        idx = topk_abs(s, tmax)
        return idx, s[idx]

    pairs = [(i, k) for k in range(n_dict) for i in range(b)]
    for (i, k), (idx, vals) in zip(pairs, parallel_map(task, pairs), strict=True):
        sq = vals.astype(np.float64) ** 2
        for j, tau in enumerate(levels):
            n, e = _count_and_error(sq, energy[i], size, tau, eps)
            counts[j, i, k], errs[j, i, k] = n, e
            key = (n, e)
            cur = best[j][i]
            # Sparsest first, then least error; strict comparison keeps the first on ties.
            if cur is None or key < cur[0]:
                best[j][i] = (key, idx[:n], vals[:n])
    out = []
    for j in range(nl):
        member = np.array(
            [int(np.lexsort((errs[j, i], counts[j, i]))[0]) for i in range(b)], dtype=np.int64
        )
        chosen = [best[j][i] for i in range(b)]
        idx_all = (
            np.concatenate([c[1] for c in chosen])
            if b  # type: ignore[index]
            else np.empty(0, dtype=np.int64)
        )
        vals_all = (
            np.concatenate([c[2] for c in chosen]).astype(np.float32)
            if b  # type: ignore[index]
            else np.empty(0, np.float32)
        )
        locs = np.stack(np.unravel_index(idx_all, shape), axis=1).astype(np.int32)
        out.append(
            SparseCodes(
                shape,
                member,
                counts[j, np.arange(b), member],
                vals_all,
                locs,
                errs[j, np.arange(b), member],
            )
        )
    return out


def reconstruct_points(
    codes: SparseCodes,
    dictionaries: Sequence[np.ndarray],
    points: Sequence[int] | np.ndarray | None = None,
    dtype: type = np.float64,
    rows: Sequence[np.ndarray | None] | None = None,
) -> np.ndarray:
    """Eq. 4 for chosen points: X = Ŝ ×_1 U1 ×_2 U2 … on each point's own dictionary.

    Returns (n, m_1, …, m_N) in the coded domain. ``rows`` restricts modes to some of their
    entries (e.g. a few lights and views: ``[None, None, lights, views]``), multiplying by those
    rows of U_n only; the output then has ``len(rows[n])`` entries on mode n.
    """
    idx = np.arange(codes.n_points) if points is None else np.asarray(points, dtype=np.int64)
    rows = list(rows) if rows is not None else [None] * len(dictionaries)
    sizes = [m if r is None else len(r) for m, r in zip(codes.mode_sizes, rows, strict=True)]
    out = np.empty((idx.size, *sizes), dtype=dtype)

    def task(j: int) -> None:
        i = int(idx[j])
        loc, val = codes.point(i)
        k = int(codes.membership[i])
        mats = [
            np.asarray(d[k] if r is None else d[k][r], dtype=dtype)
            for d, r in zip(dictionaries, rows, strict=True)
        ]
        out[j] = reconstruct_sparse(loc, val.astype(dtype, copy=False), mats)

    for _ in parallel_map(task, range(idx.size)):
        pass
    return out

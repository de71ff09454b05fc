"""Sparse codes and the count rule that makes them (paper §3.3).

:class:`SparseCodes` holds the coding of a set of data points: per point its dictionary
(membership m), its count (z), and its values and multi-index locations **sorted by decreasing
magnitude**, so a renderer can truncate τ by reading a prefix. The count rule is the
release's (``official-release-format.md`` §3 step 4): coefficients are added by decreasing
magnitude (:func:`topk_abs`) until the mean squared residual per tensor entry is <= ε or the
count reaches τ (:func:`rule_keys`). Both the coder (:mod:`.coding`) and the objective's
judgement of candidate codes (:mod:`.objective`) build on these.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ..errors import BTFInputError

__all__ = [
    "DTYPES",
    "RELEASE_EPS",
    "RELEASE_TAU",
    "RELEASE_TAU_TRAIN",
    "SparseCodes",
    "coding_rule",
    "count_and_error",
    "rule_keys",
    "topk_abs",
]

#: The release's sparsity τ per data point, (Y, U, V) (paper §4): encoding's default, the
#: split of rate control's budget, and what a fractional τ (0.25) is a fraction of.
RELEASE_TAU = (885, 64, 64)
#: The paper's training sparsity τ_l, (Y, U, V) (§4): training's default.
RELEASE_TAU_TRAIN = (256, 32, 32)
#: The release's residual threshold ε: mean squared residual per tensor entry (count rule).
RELEASE_EPS = 1e-5
#: The floating-point types coding and training compute in.
DTYPES = ("float32", "float64")


def topk_abs(c: np.ndarray, k: int, scratch: np.ndarray | None = None) -> np.ndarray:
    """Indices of the ``k`` largest |c| of a 1D array, by decreasing magnitude (ties: lower index).
    ``scratch``: a flat array of c's dtype and at least its size for |c| (reused by the caller:
    no fresh pages per call).

    Not a full sort of 2.28 M entries: the k-th largest of the maxima of 4k blocks is a lower
    bound of the k-th largest entry (k block maxima are above it), so only the entries above it
    are candidates. This keeps the selection at memory speed.
    """
    n = c.size
    k = min(k, n)
    a = np.abs(c) if scratch is None else np.abs(c, out=scratch[:n])
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


def count_and_error(
    sq_sorted: np.ndarray, energy: float, size: int, tau: int, eps: float
) -> tuple[int, float]:
    """The release's count rule on squared coefficients sorted by decreasing magnitude: one
    row of :func:`rule_keys`."""
    n, err = rule_keys(sq_sorted[None, :], energy, size, tau, eps)
    return int(n[0]), float(err[0])


def coding_rule(candidates: int | None, n_dictionaries: int) -> tuple[str, int]:
    """The dictionary rule ``candidates`` gives with K = ``n_dictionaries``: ("exhaustive", K)
    for None or >= K, else ("screened", candidates)."""
    if candidates is None or int(candidates) >= n_dictionaries:
        return "exhaustive", int(n_dictionaries)
    if int(candidates) < 1:
        raise BTFInputError(
            f"candidates must be >= 1 (or None: every dictionary), got {candidates}"
        )
    return "screened", int(candidates)


def rule_keys(
    sq_desc: np.ndarray, energy: float, size: int, tau: int, eps: float
) -> tuple[np.ndarray, np.ndarray]:
    """The release's count rule on each row of ``sq_desc`` (K, n), squared coefficients by
    decreasing magnitude: (counts (K,), errors (K,)). The count is the first n whose mean
    squared residual (energy − the n largest squares) / size is <= ε, else min(τ, n); a point
    whose energy per entry is already below ε keeps one coefficient, error ε."""
    k = sq_desc.shape[0]
    if energy / size < eps:
        return np.ones(k, dtype=np.int64), np.full(k, eps)
    resid = (energy - np.cumsum(sq_desc[:, :tau], axis=1)) / size
    hit = resid <= eps
    n = np.where(hit.any(axis=1), hit.argmax(axis=1) + 1, min(tau, sq_desc.shape[1]))
    err = np.maximum(resid[np.arange(k), n - 1], 0.0)
    return n.astype(np.int64), err

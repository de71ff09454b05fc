"""Training an ensemble of K orthonormal N-mode dictionaries (paper §3.2, Eq. 2).

Block-coordinate descent on Eq. 2a under the constraints 2b–2d
(``shared/specs/training-algorithm.md`` §4):

1. **Sparse coding + membership** (map over batches): project every point on every dictionary
   (Eq. 3), keep the τ_l largest coefficients (exact ℓ0 optimum for orthonormal bases), and
   assign each point to the dictionary of least error (Parseval, no reconstruction).
2. **Dictionary update**, one mode at a time (Gauss–Seidel): the map sums, per dictionary,
   Z⁽ⁿ'ᵏ⁾ = Σ_{i∈C_k} [X_i ×_{q≠n} U_qᵀ]_(n) [Ŝ_i]_(n)ᵀ; the reduce sets U⁽ⁿ'ᵏ⁾ = ΓΘᵀ from
   the SVD Z = ΓΣΘᵀ (orthogonal Procrustes: the maximiser of tr(UᵀZ) over orthogonal U).

Every step minimises Eq. 2a over its own block, so the objective never increases.
Each pass streams the training set in batches: memory is bounded by the batch, not the set.
:func:`code_step`, :func:`cross_products` and :func:`procrustes` are the pure map and reduce
pieces, so an iteration can run unchanged on a distributed engine (map over partitions,
sum the Z's, SVD on the driver).
"""

from __future__ import annotations

import json
import os
import time
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Protocol

import numpy as np

from .._atomic import atomic_output
from .._progress import bar
from ..errors import BTFInputError
from .coding import SparseCodes, reconstruct_points, sparse_code
from .parallel import parallel_map, prefetch
from .tensor import project, unfold

__all__ = [
    "ArraySource",
    "DictionaryEnsemble",
    "PointSource",
    "code_step",
    "cross_products",
    "hosvd_bases",
    "procrustes",
    "random_orthonormal",
]


class PointSource(Protocol):
    """A re-iterable training set of data points, streamed in batches."""

    @property
    def n_points(self) -> int: ...

    @property
    def mode_sizes(self) -> tuple[int, ...]: ...

    def batches(self, batch_size: int) -> Iterator[tuple[np.ndarray, np.ndarray]]:
        """Yield (point indices, (b, m_1, …, m_N) array) covering every point once, in order."""
        ...

    def take(self, indices: np.ndarray) -> np.ndarray:
        """The given points as one (n, m_1, …, m_N) array."""
        ...


class ArraySource:
    """A :class:`PointSource` over an in-memory (N, m_1, …, m_N) array."""

    def __init__(self, data: np.ndarray) -> None:
        if data.ndim < 2:
            raise BTFInputError(
                f"data points must be an (N, m_1, ..., m_N) array, got {data.shape}"
            )
        self.data = data

    @property
    def n_points(self) -> int:
        return int(self.data.shape[0])

    @property
    def mode_sizes(self) -> tuple[int, ...]:
        return tuple(int(s) for s in self.data.shape[1:])

    def batches(self, batch_size: int) -> Iterator[tuple[np.ndarray, np.ndarray]]:
        for s in range(0, self.n_points, batch_size):
            idx = np.arange(s, min(s + batch_size, self.n_points))
            yield idx, self.data[idx]

    def take(self, indices: np.ndarray) -> np.ndarray:
        return self.data[np.asarray(indices)]


def random_orthonormal(m: int, rng: np.random.Generator) -> np.ndarray:
    """Haar-random orthonormal matrix: QR of a Gaussian with column signs fixed by diag(R)."""
    q, r = np.linalg.qr(rng.standard_normal((m, m)))
    return q * np.sign(np.where(np.diag(r) == 0, 1, np.diag(r)))


def hosvd_bases(point: np.ndarray) -> list[np.ndarray]:
    """Per-mode left singular vectors of one data point (complete square bases)."""
    bases = []
    x = np.asarray(point, dtype=np.float64)
    for n in range(x.ndim):
        xn = unfold(x, n)
        # Eigenvectors of the m×m Gram matrix: the left singular vectors, without the huge V.
        w, u = np.linalg.eigh(xn @ xn.T)
        bases.append(u[:, np.argsort(-w, kind="stable")])
    return bases


def procrustes(z: np.ndarray) -> np.ndarray:
    """Orthogonal Procrustes: the orthogonal U maximising tr(UᵀZ), U = ΓΘᵀ for Z = ΓΣΘᵀ."""
    u, _, vt = np.linalg.svd(z)
    return u @ vt


def code_step(
    batch: np.ndarray,
    dictionaries: Sequence[np.ndarray],
    tau: int,
    eps: float = 0.0,
    dtype: type = np.float32,
) -> SparseCodes:
    """Map step 1: sparse coding and membership of one batch (Eq. 3, hard thresholding)."""
    return sparse_code(batch, dictionaries, tau, eps, dtype)


def cross_products(
    batch: np.ndarray,
    codes: SparseCodes,
    dictionaries: Sequence[np.ndarray],
    mode: int,
    dtype: type = np.float32,
) -> np.ndarray:
    """Map step 2: this batch's share of Z⁽ⁿ'ᵏ⁾ for every k, shape (K, m_n, m_n), float64.

    Z⁽ⁿ'ᵏ⁾ = Σ_i [P_i]_(n) [Ŝ_i]_(n)ᵀ with the partial projection P_i = X_i ×_{q≠n} U_qᵀ. Ŝ_i
    is sparse, so column l_n(s) of Z gains v_s times the mode-n fibre of P_i at the other
    indices of coefficient s: τ fibre gathers instead of a dense product.
    """
    n_dict = dictionaries[0].shape[0]
    m = dictionaries[mode].shape[1]
    z = np.zeros((n_dict, m, m))
    offsets = codes.offsets

    def task(b: int) -> tuple[int, np.ndarray] | None:
        k = int(codes.membership[b])
        lo, hi = offsets[b], offsets[b + 1]
        if hi == lo:
            return None
        mats = [np.asarray(d[k], dtype=dtype) for d in dictionaries]
        p = project(np.asarray(batch[b : b + 1], dtype=dtype), mats, skip=mode)[0]
        p = np.moveaxis(p, mode, -1)
        loc = codes.locations[lo:hi]
        other = tuple(loc[:, q] for q in range(loc.shape[1]) if q != mode)
        fibres = p[other].astype(np.float64) * codes.values[lo:hi, None].astype(np.float64)
        part = np.zeros((m, m))
        # Z[:, l_n] += v · fibre, accumulated by target column.
        np.add.at(part.T, loc[:, mode], fibres)
        return k, part

    for res in parallel_map(task, range(batch.shape[0])):
        if res is not None:
            z[res[0]] += res[1]
    return z


def _as_source(x: np.ndarray | PointSource) -> PointSource:
    return ArraySource(x) if isinstance(x, np.ndarray) else x


class DictionaryEnsemble:
    """An ensemble of K orthonormal N-mode dictionaries, learned by Eq. 2 (paper §3.2).

    Parameters
    ----------
    n_dictionaries : K (paper: 8).
    tau : training sparsity τ_l (paper: Y 256, U 32, V 32).
    eps : optional training error threshold ε_l (0: membership by least error at τ_l).
    max_iter : maximum number of iterations (update + coding).
    tol : stop when the relative decrease of the objective falls below it.
    init : "points" (per-mode HOSVD of K random training points) or "random" (Haar-random).
    reseed_empty : re-seed a dictionary left without members from the worst-fitted point.
    batch_size : data points per map task.
    dtype : projection arithmetic ("float32" or "float64"); sums are always float64.
    random_state : seed of every random choice.
    checkpoint : path of a file saved after each iteration; ``fit`` resumes from it.
    progress : show a progress bar (None: when stderr is a terminal).

    Attributes
    ----------
    dictionaries_ : list over modes of (K, m_n, m_n) float64, ordered by decreasing use.
    membership_ : (N,) dictionary of each training point (after the final coding).
    counts_ : (K,) members per dictionary (the release's ``EnsHist``).
    objective_ : mean squared error per entry after each coding step (non-increasing).
    n_iter_ : iterations run.
    fit_seconds_ : wall time of ``fit``.
    """

    def __init__(
        self,
        n_dictionaries: int = 8,
        tau: int = 32,
        eps: float = 0.0,
        max_iter: int = 10,
        tol: float = 1e-4,
        init: str = "points",
        reseed_empty: bool = True,
        batch_size: int = 4,
        dtype: str = "float32",
        random_state: int = 0,
        checkpoint: str | os.PathLike[str] | None = None,
        progress: bool | None = None,
    ) -> None:
        self.n_dictionaries = n_dictionaries
        self.tau = tau
        self.eps = eps
        self.max_iter = max_iter
        self.tol = tol
        self.init = init
        self.reseed_empty = reseed_empty
        self.batch_size = batch_size
        self.dtype = dtype
        self.random_state = random_state
        self.checkpoint = checkpoint
        self.progress = progress

    # -- public API ----------------------------------------------------------------------
    def fit(self, x: np.ndarray | PointSource, desc: str = "train") -> DictionaryEnsemble:
        """Learn the ensemble from data points (array (N, m_1, …) or a :class:`PointSource`)."""
        self._validate()
        src = _as_source(x)
        t0 = time.perf_counter()
        dt = np.dtype(self.dtype).type
        dicts, objective, start = self._resume(src)
        if dicts is None:
            dicts = self._initialise(src)
            objective = []
        codes = self._code_all(src, dicts, dt, f"{desc} code")
        if not objective:
            objective.append(float(codes.errors.mean()))
        used_for_reseed: set[int] = set()
        it = start
        for it in range(start, self.max_iter):
            self._reseed(src, dicts, codes, used_for_reseed)
            for mode in range(len(dicts)):
                z = np.zeros((self.n_dictionaries, dicts[mode].shape[1], dicts[mode].shape[1]))
                with bar(
                    src.n_points, f"{desc} it{it + 1} mode{mode + 1}", "pt", self.progress
                ) as pb:
                    for idx, xb in prefetch(src.batches(self.batch_size)):
                        z += cross_products(xb, _slice_codes(codes, idx), dicts, mode, dt)
                        pb.update(len(idx))
                for k in np.flatnonzero(
                    np.bincount(codes.membership, minlength=self.n_dictionaries)
                ):
                    dicts[mode][k] = procrustes(z[k])
            codes = self._code_all(src, dicts, dt, f"{desc} it{it + 1} code")
            objective.append(float(codes.errors.mean()))
            self._save_checkpoint(dicts, objective, it + 1)
            prev, cur = objective[-2], objective[-1]
            if prev <= 0 or (prev - cur) / prev < self.tol:
                it += 1
                break
        else:
            it = self.max_iter
        counts = np.bincount(codes.membership, minlength=self.n_dictionaries)
        order = np.argsort(-counts, kind="stable")
        rank = np.empty_like(order)
        rank[order] = np.arange(order.size)
        self.dictionaries_ = [d[order].copy() for d in dicts]
        self.membership_ = rank[codes.membership]
        self.counts_ = counts[order]
        self.objective_ = objective
        self.n_iter_ = max(it, start)
        self.mode_sizes_ = src.mode_sizes
        self.fit_seconds_ = time.perf_counter() - t0
        return self

    def transform(self, x: np.ndarray, tau: int | None = None, eps: float = 0.0) -> SparseCodes:
        """Sparse codes of data points (§3.3 rule; τ defaults to the training τ_l)."""
        self._check_fitted()
        return sparse_code(x, self.dictionaries_, tau or self.tau, eps, np.dtype(self.dtype).type)

    def inverse_transform(self, codes: SparseCodes) -> np.ndarray:
        """Eq. 4: data points back from their codes."""
        self._check_fitted()
        return reconstruct_points(codes, self.dictionaries_)

    # -- steps ------------------------------------------------------------------------------
    def _validate(self) -> None:
        if self.n_dictionaries < 1 or self.n_dictionaries > 255:
            raise BTFInputError(f"n_dictionaries must be in [1, 255], got {self.n_dictionaries}")
        if self.tau < 1:
            raise BTFInputError(f"training sparsity tau must be >= 1, got {self.tau}")
        if self.init not in ("points", "random"):
            raise BTFInputError(f"init must be 'points' or 'random', got {self.init!r}")
        if self.dtype not in ("float32", "float64"):
            raise BTFInputError(f"dtype must be 'float32' or 'float64', got {self.dtype!r}")

    def _check_fitted(self) -> None:
        if not hasattr(self, "dictionaries_"):
            raise BTFInputError("this ensemble is not fitted yet; call fit() first")

    def _initialise(self, src: PointSource) -> list[np.ndarray]:
        rng = np.random.default_rng(self.random_state)
        k = self.n_dictionaries
        dicts = [np.empty((k, m, m)) for m in src.mode_sizes]
        if self.init == "points":
            n_seed = min(k, src.n_points)
            seeds = np.sort(rng.choice(src.n_points, size=n_seed, replace=False))
            pts = src.take(seeds)
            for j in range(n_seed):
                for mode, u in enumerate(hosvd_bases(pts[j])):
                    dicts[mode][j] = u
            start = n_seed
        else:
            start = 0
        for j in range(start, k):
            for mode, m in enumerate(src.mode_sizes):
                dicts[mode][j] = random_orthonormal(m, rng)
        return dicts

    def _code_all(
        self, src: PointSource, dicts: list[np.ndarray], dt: type, desc: str
    ) -> SparseCodes:
        parts = []
        with bar(src.n_points, desc, "pt", self.progress) as pb:
            for _, xb in prefetch(src.batches(self.batch_size)):
                parts.append(code_step(xb, dicts, self.tau, self.eps, dt))
                pb.update(xb.shape[0])
        return SparseCodes.concatenate(parts)

    def _reseed(
        self, src: PointSource, dicts: list[np.ndarray], codes: SparseCodes, used: set[int]
    ) -> None:
        if not self.reseed_empty:
            return
        counts = np.bincount(codes.membership, minlength=self.n_dictionaries)
        empty = np.flatnonzero(counts == 0)
        if empty.size == 0:
            return
        worst = [int(i) for i in np.argsort(-codes.errors, kind="stable") if int(i) not in used]
        for k, i in zip(empty, worst, strict=False):
            used.add(i)
            for mode, u in enumerate(hosvd_bases(src.take(np.array([i]))[0])):
                dicts[mode][k] = u

    # -- checkpoints ----------------------------------------------------------------------
    def _params_key(self, src: PointSource) -> str:
        return json.dumps(
            {
                "K": self.n_dictionaries,
                "tau": self.tau,
                "eps": self.eps,
                "init": self.init,
                "seed": self.random_state,
                "dtype": self.dtype,
                "n": src.n_points,
                "shape": list(src.mode_sizes),
            },
            sort_keys=True,
        )

    def _save_checkpoint(self, dicts: list[np.ndarray], objective: list[float], it: int) -> None:
        if self.checkpoint is None:
            return
        path = Path(self.checkpoint)
        with atomic_output(path) as tmp:
            with open(tmp, "wb") as f:
                np.savez(
                    f,
                    iteration=it,
                    objective=np.array(objective),
                    key=self._key,
                    **{f"mode{n}": d for n, d in enumerate(dicts)},
                )

    def _resume(self, src: PointSource) -> tuple[list[np.ndarray] | None, list[float], int]:
        self._key = self._params_key(src)
        if self.checkpoint is None or not Path(self.checkpoint).exists():
            return None, [], 0
        with np.load(self.checkpoint) as ck:
            if str(ck["key"]) != self._key:
                raise BTFInputError(
                    f"checkpoint {self.checkpoint} was made with other training parameters or "
                    "data; delete it or choose another checkpoint path"
                )
            dicts = [ck[f"mode{n}"].copy() for n in range(len(src.mode_sizes))]
            return dicts, [float(v) for v in ck["objective"]], int(ck["iteration"])


def _slice_codes(codes: SparseCodes, idx: np.ndarray) -> SparseCodes:
    """Codes of a contiguous run of points (a batch)."""
    lo, hi = int(idx[0]), int(idx[-1]) + 1
    o = codes.offsets
    return SparseCodes(
        codes.mode_sizes,
        codes.membership[lo:hi],
        codes.counts[lo:hi],
        codes.values[o[lo] : o[hi]],
        codes.locations[o[lo] : o[hi]],
        codes.errors[lo:hi],
    )

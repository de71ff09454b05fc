"""Training an ensemble of K orthonormal N-mode dictionaries (paper §3.2, Eq. 2).

Block-coordinate descent on Eq. 2a under the constraints 2b–2d
(``shared/specs/training-algorithm.md`` §4). One iteration:

1. **Dictionary update**, one mode at a time (Gauss–Seidel): per dictionary,
   Z⁽ⁿ'ᵏ⁾ = Σ_{i∈C_k} [X_i ×_{q≠n} U_qᵀ]_(n) [Ŝ_i]_(n)ᵀ, then U⁽ⁿ'ᵏ⁾ = ΓΘᵀ from the SVD
   Z = ΓΣΘᵀ (orthogonal Procrustes: the maximiser of tr(UᵀZ) over orthogonal U). Z is built
   from the τ_l coefficients of each point (:mod:`.steps`); the last two modes of the
   projection order come free with the previous coding pass, the others take one pass each.
2. **Sparse coding + membership**: project every point on its candidate dictionaries (Eq. 3),
   keep the τ_l largest coefficients (exact ℓ0 optimum for orthonormal bases) and assign it
   to the candidate of least error (Parseval, no reconstruction).

**Candidates.** Memberships settle after the first iterations, so projecting every point on
all K dictionaries every iteration is mostly wasted. A *full* pass tries all K and ranks
them per point; the passes in between (*partial*) try only each point's ``candidates`` best
of the last full pass, which include its current dictionary. Every ``full_pass_every``-th
iteration, the last iteration and any iteration that meets the tolerance end with a full
pass, so a full pass always decides the final memberships; a dictionary re-seeded after a full
pass is tried by every point in the next pass. ``candidates >= K`` is the exhaustive trainer.

Every step minimises Eq. 2a over its own block (the update with Ŝ and M fixed; the coding over
a set of dictionaries that contains the current one), so the objective never increases.
Each pass is one task per partition of :data:`~.partitions.PARTITION_POINTS` points on an
executor (:mod:`.partitions`, :mod:`sparsebtf.execution`): in this process by default, streaming
the training set in batches (memory bounded by the batch, not the set), or on a Dask cluster
where each partition stays in a worker's memory across iterations. The Z's are summed in one
fixed order, so both give the same dictionaries; the SVDs run here.
"""

from __future__ import annotations

import copy
import functools
import json
import math
import os
import time
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from .._semantic import check_orthonormal
from .._threads import parallel_map
from ..checkpoints import check_key, read_checkpoint, write_checkpoint
from ..errors import BTFInputError, FileFormatError
from ..execution import Executor, InProcess
from .codes import DTYPES, SparseCodes
from .coding import reconstruct_points, sparse_code
from .init import hosvd_bases, preclustered_dictionaries, random_orthonormal
from .partitions import (
    PARTITION_POINTS,
    ArraySource,
    Coded,
    coding_pass,
    cross_pass,
    load_points,
    part_of,
    partition_bounds,
)
from .state import TRAIN_FIELDS, TrainState, check_state, keep_current, with_extra
from .steps import (
    code_step,
    cross_products,
    pair_cross_products,
    pair_modes,
    procrustes,
    sparse_cross_products,
)
from .tau_levels import VALIDATION, check_layout, check_levels, fit_levels

__all__ = [
    "CANDIDATES",
    "EXHAUSTIVE_MAX_ENTRIES",
    "FULL_PASS_EVERY",
    "INITS",
    "UPDATES",
    "ArraySource",
    "DictionaryEnsemble",
    "PointSource",
    "code_step",
    "cross_products",
    "hosvd_bases",
    "procrustes",
    "random_orthonormal",
    "sparse_cross_products",
]

#: Default dictionaries tried per point between full coding passes (``benchmarks/bench_training.py``
#: and docs/benchmarks.md §2 measure what it saves and what it costs in objective).
CANDIDATES = 1
#: Default period of the full coding passes, in iterations (0: only those that must be full).
FULL_PASS_EVERY = 10
#: The default (``candidates=None``) is the exhaustive trainer when a full coding pass
#: projects at most this many tensor entries (points x K x entries per point): 2^29, e.g. 29
#: points of 10x10x151x151 at K = 8, about 4 s of projections per pass on 2 cores. On such
#: problems the candidate schedule ended 1-8 % above the exhaustive objective
#: (docs/benchmarks.md §2, "Small problems"), and a full pass costs little.
EXHAUSTIVE_MAX_ENTRIES = 2**29

#: How Z⁽ⁿ'ᵏ⁾ is built: from the codes (fast) or from dense partial projections (reference).
UPDATES = ("codes", "projections")
#: How the dictionaries start (:mod:`.init`): from the HOSVD bases of random points,
#: Haar-random, or from groups of points with alike sparsity patterns (pre-clustered).
INITS = ("points", "random", "preclustered")


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

    def part(self, lo: int, hi: int) -> PointSource:
        """Points ``[lo, hi)`` as a source (optional: a view through ``take`` otherwise)."""
        ...


def _as_source(x: np.ndarray | PointSource) -> PointSource:
    return ArraySource(x) if isinstance(x, np.ndarray) else x


class DictionaryEnsemble:
    """An ensemble of K orthonormal N-mode dictionaries, learned by Eq. 2 (paper §3.2).

    Parameters
    ----------
    n_dictionaries : K (paper: 8).
    tau : training sparsity τ_l (paper: Y 256, U 32, V 32); a sequence of several τ_l splits
        the K dictionaries evenly over them, each trained at its own (:mod:`.tau_levels`).
    learn_tau : with several ``tau``: they are a candidate grid, and each dictionary's τ_l is
        chosen by the error on a held-out validation split (:mod:`.tau_levels`).
    validation : the fraction of the training points held out for ``learn_tau``.
    validation_taus : the coding τ_t the validation error is measured at for ``learn_tau``
        (None: the levels of ``tau``); they should be the τ_t the model will be coded at.
    eps : optional training error threshold ε_l (0: membership by least error at τ_l).
    max_iter : maximum number of iterations (update + coding).
    tol : stop when an iteration ending in a full pass lowers the objective by less than
        this fraction.
    init : "points" (per-mode HOSVD of K random training points), "random" (Haar-random) or
        "preclustered" (per-mode HOSVD of K groups of points with alike sparsity patterns
        under a DCT basis, :mod:`.init`).
    reseed_empty : re-seed a dictionary left without members from the worst-fitted point.
    candidates : dictionaries tried per point in a partial coding pass: its best ones at the
        last full pass (module docstring). ``>= n_dictionaries``: every pass is full. None
        (default): all K when a full pass is cheap (at most :data:`EXHAUSTIVE_MAX_ENTRIES`
        entries projected), else :data:`CANDIDATES` (:meth:`candidates_for`).
    full_pass_every : every this-many-th iteration ends with a full pass (0: only the
        iterations that must: after a re-seed, on meeting ``tol``, the last one).
    update : how Z⁽ⁿ'ᵏ⁾ is built: "codes" (from the τ_l coefficients, :mod:`.steps`) or
        "projections" (dense partial projections, the reference; same Z, ~10× the FLOPs).
    batch_size : data points read at a time (memory bound in process; no effect on the
        result).
    partition_size : data points per task (:mod:`.partitions`): the unit of work on a cluster
        and of the fixed summation order (part of the result, recorded in checkpoints).
    dtype : projection arithmetic ("float32" or "float64"); sums are always float64.
    random_state : seed of every random choice.
    checkpoint : path of a file saved after each iteration; ``fit`` resumes from it (an
        error if it was made with other parameters or data).
    progress : show a progress bar (None: when stderr is a terminal).

    Attributes
    ----------
    dictionaries_ : list over modes of (K, m_n, m_n) float64, ordered by decreasing use.
    membership_ : (N,) dictionary of each training point (after the final, full, coding);
        with several τ_l, (N, L): each level's own membership (:mod:`.tau_levels`).
    taus_ : (K,) the training τ_l of each dictionary.
    counts_ : (K,) members per dictionary (the release's ``EnsHist``).
    objective_ : mean squared error per entry after each coding step (non-increasing).
    passes_ : "full" or "partial" for each coding step of ``objective_``.
    candidates_ : dictionaries tried per point in the partial passes (K: every pass full).
    n_iter_ : iterations run.
    iteration_seconds_ : wall time of each iteration run by this ``fit`` (update + coding).
    iteration_cpu_seconds_ : CPU time of this process (all threads) in each of them.
    fit_seconds_ : wall time of ``fit``.
    """

    def __init__(
        self,
        n_dictionaries: int = 8,
        tau: int | Sequence[int] = 32,
        eps: float = 0.0,
        max_iter: int = 10,
        tol: float = 1e-4,
        init: str = "points",
        reseed_empty: bool = True,
        candidates: int | None = None,
        full_pass_every: int = FULL_PASS_EVERY,
        update: str = "codes",
        batch_size: int = 4,
        partition_size: int = PARTITION_POINTS,
        dtype: str = "float32",
        random_state: int = 0,
        checkpoint: str | os.PathLike[str] | None = None,
        progress: bool | None = None,
        learn_tau: bool = False,
        validation: float = VALIDATION,
        validation_taus: Sequence[int] | None = None,
    ) -> None:
        self.n_dictionaries = n_dictionaries
        self.tau = tau
        self.eps = eps
        self.max_iter = max_iter
        self.tol = tol
        self.init = init
        self.reseed_empty = reseed_empty
        self.candidates = candidates
        self.full_pass_every = full_pass_every
        self.update = update
        self.batch_size = batch_size
        self.partition_size = partition_size
        self.dtype = dtype
        self.random_state = random_state
        self.checkpoint = checkpoint
        self.progress = progress
        self.learn_tau = learn_tau
        self.validation = validation
        self.validation_taus = validation_taus
        #: entries added to the checkpoint key (a level of a several-τ_l ensemble)
        self.key_extra: dict[str, Any] = {}

    # -- public API ----------------------------------------------------------------------
    def fit(
        self,
        x: np.ndarray | PointSource,
        desc: str = "train",
        *,
        executor: Executor | None = None,
        partition: Callable[[int, int, int], Any] | None = None,
        data_key: str = "",
    ) -> DictionaryEnsemble:
        """Learn the ensemble from data points (array (N, m_1, …) or a :class:`PointSource`).

        ``executor`` runs the passes (default: this process; :mod:`sparsebtf.execution`).
        ``partition(lo, hi, slot)`` gives a handle on the executor on points ``[lo, hi)`` as a
        point source (default: a view of ``x`` in process; on a cluster a task that loads
        ``x.part(lo, hi)``, which should then describe its points rather than hold them);
        ``slot`` numbers the partitions, to spread them over the workers (``submit(place=)``).
        ``data_key`` names the training data in checkpoints (a resume on other data fails).
        """
        self._validate()
        src = _as_source(x)
        if self.learn_tau or len(self.levels) > 1:
            return fit_levels(self, src, desc, executor, partition, data_key)
        check_layout(self.checkpoint, several=False)
        ex = executor if executor is not None else InProcess()
        t0 = time.perf_counter()
        dt = np.dtype(self.dtype).type
        n_cand = self.candidates_for(src.n_points, src.mode_sizes)
        bounds = partition_bounds(src.n_points, self.partition_size)
        if partition is None:
            partition = functools.partial(_default_partition, ex, src, self.batch_size)
        parts = [partition(lo, hi, i) for i, (lo, hi) in enumerate(bounds)]

        def code(dicts: list[np.ndarray], ranking: np.ndarray | None, label: str) -> Coded:
            return coding_pass(ex, parts, bounds, dicts, self.tau, self.eps, dt, ranking,
                               self.batch_size, label, self.progress)  # fmt: skip

        state = self._resume(src, data_key)
        if state is None:
            state = TrainState(self._initialise(src), [], [], 0)
            coding = code(state.dicts, None, f"{desc} code")
            state.objective.append(float(coding.errors.mean()))
            state.passes.append("full")
            state.ranking = coding.ranking[:, :n_cand]
        else:
            partial = state.passes[-1] == "partial"
            coding = code(state.dicts, state.ranking if partial else None, f"{desc} code")
        self.iteration_seconds_: list[float] = []
        self.iteration_cpu_seconds_: list[float] = []
        for it in range(state.iteration, self.max_iter):
            if state.converged:
                break
            t_it, cpu_it = time.perf_counter(), time.process_time()
            reseeded = self._reseed(src, state, coding)
            self._update_dictionaries(ex, parts, bounds, state.dicts, coding, dt,
                                      f"{desc} it{it + 1}")  # fmt: skip
            full = (
                n_cand >= self.n_dictionaries
                or it + 1 == self.max_iter
                or (self.full_pass_every > 0 and (it + 1) % self.full_pass_every == 0)
            )
            label = f"{desc} it{it + 1} code"
            cand = None if full else with_extra(state.ranking, reseeded)
            coding = code(state.dicts, cand, label)
            if not full:
                keep_current(state.ranking, coding.membership)
            done = self._converged(state.objective[-1], coding)
            if done and not full:
                # Memberships may still move: only a full pass can confirm convergence.
                full = True
                coding = code(state.dicts, None, f"{label} (full)")
                done = self._converged(state.objective[-1], coding)
            state.objective.append(float(coding.errors.mean()))
            state.passes.append("full" if full else "partial")
            if full:
                state.ranking = coding.ranking[:, :n_cand]
            state.iteration = it + 1
            state.converged = done
            self._save_checkpoint(state)
            self.iteration_seconds_.append(time.perf_counter() - t_it)
            self.iteration_cpu_seconds_.append(time.process_time() - cpu_it)
            if done:
                break
        if state.passes[-1] != "full":
            # Resumed past max_iter after a partial pass: the final memberships need a full one.
            coding = code(state.dicts, None, f"{desc} code (full)")
            state.objective[-1] = float(coding.errors.mean())
            state.passes[-1] = "full"
        counts = np.bincount(coding.membership, minlength=self.n_dictionaries)
        order = np.argsort(-counts, kind="stable")
        rank = np.empty_like(order)
        rank[order] = np.arange(order.size)
        self.dictionaries_ = [d[order].copy() for d in state.dicts]
        self.membership_ = rank[coding.membership]
        self.counts_ = counts[order]
        self.objective_ = state.objective
        self.passes_ = state.passes
        self.candidates_ = n_cand
        self.n_iter_ = state.iteration
        self.mode_sizes_ = src.mode_sizes
        self.taus_ = [self.levels[0]] * self.n_dictionaries
        self.fit_seconds_ = time.perf_counter() - t0
        return self

    def transform(self, x: np.ndarray, tau: int | None = None, eps: float = 0.0) -> SparseCodes:
        """Sparse codes of data points (§3.3 rule; τ defaults to the training τ_l)."""
        self._check_fitted()
        tau = tau or max(self.levels)
        return sparse_code(x, self.dictionaries_, tau, eps, np.dtype(self.dtype).type)

    def inverse_transform(self, codes: SparseCodes) -> np.ndarray:
        """Eq. 4: data points back from their codes."""
        self._check_fitted()
        return reconstruct_points(codes, self.dictionaries_)

    def candidates_for(self, n_points: int, mode_sizes: tuple[int, ...]) -> int:
        """Dictionaries tried per point in a partial pass on ``n_points`` training points of
        shape ``mode_sizes``: ``candidates`` if given, else all K (the exhaustive trainer) when
        a full pass projects at most :data:`EXHAUSTIVE_MAX_ENTRIES` entries
        (``n_points · K · prod(mode_sizes)``), else :data:`CANDIDATES`."""
        k = self.n_dictionaries
        if self.candidates is not None:
            return min(self.candidates, k)
        entries = n_points * k * math.prod(mode_sizes)
        return k if entries <= EXHAUSTIVE_MAX_ENTRIES else min(CANDIDATES, k)

    @property
    def levels(self) -> list[int]:
        """The training sparsities τ_l asked for (one, or several levels)."""
        return [int(self.tau)] if np.ndim(self.tau) == 0 else [int(t) for t in self.tau]

    def level_estimator(
        self, tau: int, n_dictionaries: int, seed: int, checkpoint: str | None,
        key: dict[str, Any],
    ) -> DictionaryEnsemble:  # fmt: skip
        """This ensemble's parameters at one τ_l (a level of a several-τ_l ensemble)."""
        sub = copy.copy(self)
        sub.tau, sub.n_dictionaries, sub.random_state = tau, n_dictionaries, seed
        sub.learn_tau, sub.checkpoint, sub.key_extra = False, checkpoint, key
        return sub

    # -- steps ------------------------------------------------------------------------------
    def _validate(self) -> None:
        if self.n_dictionaries < 1 or self.n_dictionaries > 255:
            raise BTFInputError(f"n_dictionaries must be in [1, 255], got {self.n_dictionaries}")
        check_levels(self.levels, self.n_dictionaries, self.learn_tau, self.validation)
        if self.init not in INITS:
            raise BTFInputError(f"init must be one of {INITS}, got {self.init!r}")
        if self.dtype not in DTYPES:
            raise BTFInputError(f"dtype must be 'float32' or 'float64', got {self.dtype!r}")
        if self.candidates is not None and self.candidates < 1:
            raise BTFInputError(f"candidates must be >= 1, got {self.candidates}")
        if self.full_pass_every < 0:
            raise BTFInputError(f"full_pass_every must be >= 0, got {self.full_pass_every}")
        if self.partition_size < 1 or self.batch_size < 1:
            raise BTFInputError(
                f"partition_size and batch_size must be >= 1, got {self.partition_size} and "
                f"{self.batch_size}"
            )
        if self.update not in UPDATES:
            raise BTFInputError(f"update must be one of {UPDATES}, got {self.update!r}")

    def _check_fitted(self) -> None:
        if not hasattr(self, "dictionaries_"):
            raise BTFInputError("this ensemble is not fitted yet; call fit() first")

    def _converged(self, prev: float, coding: Coded) -> bool:
        cur = float(coding.errors.mean())
        return prev <= 0 or (prev - cur) / prev < self.tol

    def _initialise(self, src: PointSource) -> list[np.ndarray]:
        rng = np.random.default_rng(self.random_state)
        k = self.n_dictionaries
        dicts = [np.empty((k, m, m)) for m in src.mode_sizes]
        if self.init == "points":
            n_seed = min(k, src.n_points)
            seeds = np.sort(rng.choice(src.n_points, size=n_seed, replace=False))
            pts = src.take(seeds)
            for j, bases in enumerate(parallel_map(hosvd_bases, list(pts))):
                for mode, u in enumerate(bases):
                    dicts[mode][j] = u
            start = n_seed
        elif self.init == "preclustered":
            return preclustered_dictionaries(src, k, self.levels[0], self.random_state,
                                             self.batch_size)  # fmt: skip
        else:
            start = 0
        for j in range(start, k):
            for mode, m in enumerate(src.mode_sizes):
                dicts[mode][j] = random_orthonormal(m, rng)
        return dicts

    def _update_dictionaries(
        self, ex: Executor, parts: list[Any], bounds: list[tuple[int, int]],
        dicts: list[np.ndarray], coding: Coded, dt: type, desc: str,
    ) -> None:  # fmt: skip
        """One Gauss–Seidel sweep of Procrustes updates over the modes (codes held fixed).

        Order: the projection's last mode b, then a, then the others. With ``update="codes"``
        Z⁽ᵇ⁾ and H⁽ᵃ⁾ come from the coding pass; every other mode is one map-reduce pass.
        """
        active = np.flatnonzero(np.bincount(coding.membership, minlength=self.n_dictionaries))
        mode_b, mode_a = pair_modes([d.shape[1] for d in dicts])
        pair = [mode_b] if mode_a is None else [mode_b, mode_a]
        order = pair + [n for n in range(len(dicts)) if n not in pair]
        fast = self.update == "codes"
        for mode in order:
            if fast and mode == mode_b and coding.z_last is not None:
                z = coding.z_last
            elif fast and mode == mode_a and coding.pair is not None:
                z = np.stack([
                    pair_cross_products(coding.pair[k], dicts[mode_b][k])
                    for k in range(self.n_dictionaries)
                ])  # fmt: skip
            else:
                z = cross_pass(ex, parts, bounds, coding.codes, dicts, mode, dt, self.update,
                               self.batch_size, f"{desc} mode{mode + 1}", self.progress)
            # Single-threaded SVDs side by side: two LAPACK threads per 151×151 SVD ran 20×
            # slower whenever another process held a core.
            for k, u in zip(active, parallel_map(procrustes, list(z[active])), strict=True):
                dicts[mode][k] = u

    def _reseed(self, src: PointSource, state: TrainState, codes: Coded) -> list[int]:
        """Give each dictionary left without members the HOSVD bases of the worst-fitted point
        not used before; the re-seeded dictionaries (every point tries them next pass)."""
        if not self.reseed_empty or state.passes[-1] != "full":
            # After a partial pass a dictionary may be empty only for lack of candidates.
            return []
        counts = np.bincount(codes.membership, minlength=self.n_dictionaries)
        empty = np.flatnonzero(counts == 0)
        used = set(state.reseeded_from)
        worst = [int(i) for i in np.argsort(-codes.errors, kind="stable") if int(i) not in used]
        done = []
        for k, i in zip(empty, worst, strict=False):
            state.reseeded_from.append(i)
            done.append(int(k))
            bases = next(parallel_map(hosvd_bases, [src.take(np.array([i]))[0]]))
            for mode, u in enumerate(bases):
                state.dicts[mode][k] = u
        return done

    # -- checkpoints ----------------------------------------------------------------------
    def _params_key(self, src: PointSource, data_key: str) -> dict[str, Any]:
        return {
            "K": self.n_dictionaries,
            "tau": self.tau,
            "eps": self.eps,
            "init": self.init,
            "seed": self.random_state,
            "dtype": self.dtype,
            "candidates": self.candidates_for(src.n_points, src.mode_sizes),
            "full_pass_every": self.full_pass_every,
            "update": self.update,
            "partition_size": self.partition_size,
            "n": src.n_points,
            "shape": list(src.mode_sizes),
            "data": data_key,
            **self.key_extra,
        }

    def _save_checkpoint(self, state: TrainState) -> None:
        """Write ``state`` (``.npz``) with the SHA-256 of its arrays
        (:func:`~sparsebtf.checkpoints.write_checkpoint`), so a resumed fit can tell a damaged
        checkpoint from a good one."""
        if self.checkpoint is None:
            return
        arrays = {
            "iteration": np.asarray(state.iteration),
            "objective": np.array(state.objective, dtype=np.float64),
            "passes": np.array(state.passes),
            "ranking": np.asarray(state.ranking),
            "reseeded_from": np.array(state.reseeded_from, dtype=np.int64),
            "converged": np.asarray(state.converged),
            "key": np.asarray(json.dumps(self._key, sort_keys=True)),
            **{f"mode{n}": np.asarray(d) for n, d in enumerate(state.dicts)},
        }
        write_checkpoint(self.checkpoint, arrays)

    def _resume(self, src: PointSource, data_key: str = "") -> TrainState | None:
        self._key = self._params_key(src, data_key)
        if self.checkpoint is None or not Path(self.checkpoint).exists():
            return None
        arrays = read_checkpoint(self.checkpoint, TRAIN_FIELDS)
        where = str(self.checkpoint)
        check_key(self.checkpoint, json.loads(str(arrays["key"])), self._key)
        dicts = [arrays.get(f"mode{n}") for n in range(len(src.mode_sizes))]
        for n, (u, m) in enumerate(zip(dicts, src.mode_sizes, strict=True), start=1):
            want = (self.n_dictionaries, m, m)
            if u is None or u.shape != want or u.dtype.kind != "f":
                found = "nothing" if u is None else f"{u.dtype} {u.shape}"
                raise FileFormatError(f"{where}: mode{n}: expected float {want}, found {found}")
        check_orthonormal(dicts, where)
        state = TrainState(
            [u.copy() for u in dicts],
            [float(v) for v in np.atleast_1d(arrays["objective"])],
            [str(v) for v in np.atleast_1d(arrays["passes"])],
            int(arrays["iteration"]),
            np.asarray(arrays["ranking"]).copy(),
            [int(v) for v in np.atleast_1d(arrays["reseeded_from"])],
            bool(arrays["converged"]),
        )
        check_state(state, src.n_points, self.n_dictionaries, where)
        return state


def _default_partition(ex: Executor, src: PointSource, batch_size: int, lo: int, hi: int,
                       slot: int) -> Any:  # fmt: skip
    """In process, a view of ``src`` (read batch by batch at each pass); on a cluster, a task
    that loads the points into a worker's memory once."""
    part = part_of(src, lo, hi)
    if ex.distributed:
        return ex.submit(load_points, part, batch_size, place=slot)
    return ex.constant(part)

"""Ensembles trained at several τ_l (beyond the paper: its §3.3 and §5 leave them to future work).

**Several levels** (``tau=[64, 256, 885]``): the K dictionaries are split evenly over the L
levels, and the K/L dictionaries of level l are an ensemble of their own, trained by Eq. 2 at
τ_l on *all* the training points (each point belongs to one dictionary per level; the coding
step and the update of level l use τ_l). One membership over all K would not do: by the least
error rule every point would go to a dictionary of the largest τ_l (more coefficients, less
error), leaving the other levels empty. The coder's rule is unchanged: at coding time each
point picks, at the coded τ_t, its best dictionary among all K, whatever τ_l shaped it.
Cost: L fits of K/L dictionaries each. The coding passes project each point on K dictionaries
in all, as one K ensemble; the dictionary updates cost L times one fit's (each point updates
one dictionary per level).

**Learned levels** (``learn_tau=True``, the paper's §5 ideal): the levels are a candidate grid
G, and each dictionary's τ_l is chosen by the error on a validation split:

1. A seeded fraction ``validation`` of the training partitions (blocks of ``partition_size``
   points, :mod:`.partitions`) is held out; the ensembles are trained on the rest.
2. A pool: at every τ of G, an ensemble of K dictionaries (L·K dictionaries, L fits).
3. Every held-out point is projected on every pool dictionary (L·K projections per point);
   its error at each coding level τ_c (``validation_taus``: the τ_t the model will be coded
   at; by default the levels of G) is Parseval's (‖X‖² − the τ_c largest squared
   coefficients) / size. The ensemble's error at τ_c is the coder's: the least over its
   dictionaries.
4. Forward selection of K dictionaries from the pool: each step adds the one that most lowers
   the mean over the τ_c of log(mean validation error at τ_c) (equal weight to every level, as
   a mean PSNR; ties to the lower pool index). A dictionary's τ_l is the level it was trained
   at.

Cost: L times the training of one ensemble of K, plus one projection of each validation point
on L·K dictionaries (the ensembles see only 1 − ``validation`` of the points).

Every level is a :class:`~.ensemble.DictionaryEnsemble` fit with its own checkpoint
(``<checkpoint>_level<l>.npz``, its key holding the levels, ``learn_tau``, ``validation`` and the
level) and seed (``random_state + LEVEL_SEED · l``), so ``--resume``, Dask and the
checkpoints work as for one level; the selection is a pure function of the fitted levels.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np

from .._threads import parallel_map
from ..errors import BTFInputError
from .codes import topk_abs
from .partitions import RangeSource, part_of, partition_bounds
from .tensor import project

__all__ = [
    "LEVEL_SEED",
    "VALIDATION",
    "PartsSource",
    "check_layout",
    "check_levels",
    "fit_levels",
    "forward_selection",
    "level_checkpoint",
    "validation_errors",
]

#: Default fraction of the training partitions held out to learn the τ_l.
VALIDATION = 0.2
#: Level l's seed is ``random_state + LEVEL_SEED * l`` (level 0: the one-level seed).
LEVEL_SEED = 1000
#: Seed offset of the validation split.
SPLIT_SEED = 77


def check_levels(levels: list[int], k: int, learn: bool, validation: float) -> None:
    """One line for training sparsities that cannot be trained."""
    if not levels or any(t < 1 for t in levels):
        raise BTFInputError(f"training sparsity tau must be >= 1 at every level, got {levels}")
    if learn:
        if not 0 < validation < 1:
            raise BTFInputError(f"validation must be a fraction in (0, 1), got {validation}")
        return
    if k % len(levels):
        raise BTFInputError(
            f"{k} dictionaries cannot be split evenly over {len(levels)} training sparsity "
            f"levels {levels}: give a number of dictionaries that is a multiple of "
            f"{len(levels)} (e.g. {len(levels) * -(-k // len(levels))})"
        )


def level_checkpoint(checkpoint: str | Path, level: int) -> str:
    """The checkpoint file of level ``level`` (0-based) of a several-τ_l fit."""
    p = Path(checkpoint)
    return str(p.with_name(f"{p.stem}_level{level + 1}{p.suffix or '.npz'}"))


def check_layout(checkpoint: Any, several: bool) -> None:
    """Refuse to resume a one-level fit from several-level checkpoints, and the reverse."""
    if checkpoint is None:
        return
    p = Path(checkpoint)
    levels = sorted(q.name for q in p.parent.glob(f"{p.stem}_level*{p.suffix or '.npz'}"))
    if not several and levels:
        raise BTFInputError(
            f"checkpoint {p}: {p.parent} holds checkpoints of a run with several training "
            f"sparsity levels ({', '.join(levels[:3])}); resume with the same tau_train, or "
            "delete them"
        )
    if several and p.exists():
        raise BTFInputError(
            f"checkpoint {p} was made with one training sparsity level; resume with the same "
            "tau_train, or delete it"
        )


class PartsSource:
    """A point source over whole partitions ``ranges`` of another (the training split)."""

    def __init__(self, source: Any, ranges: list[tuple[int, int]]) -> None:
        self.source, self.ranges = source, ranges
        self.offsets = np.cumsum([0] + [hi - lo for lo, hi in ranges])
        self.index = np.concatenate([np.arange(lo, hi) for lo, hi in ranges])

    @property
    def n_points(self) -> int:
        return int(self.offsets[-1])

    @property
    def mode_sizes(self) -> tuple[int, ...]:
        return tuple(self.source.mode_sizes)

    def batches(self, batch_size: int) -> Iterator[tuple[np.ndarray, np.ndarray]]:
        for off, (lo, hi) in zip(self.offsets, self.ranges, strict=False):
            for idx, xb in part_of(self.source, lo, hi).batches(batch_size):
                yield idx + off, xb

    def take(self, indices: np.ndarray) -> np.ndarray:
        return self.source.take(self.index[np.asarray(indices)])

    def part(self, lo: int, hi: int) -> Any:
        j = int(np.searchsorted(self.offsets, lo, side="right")) - 1
        if hi <= self.offsets[j + 1]:
            base = self.ranges[j][0] - int(self.offsets[j])
            return part_of(self.source, base + lo, base + hi)
        return RangeSource(self, lo, hi)


def _split(n: int, size: int, fraction: float, seed: int
           ) -> tuple[list[tuple[int, int]], list[tuple[int, int]]]:  # fmt: skip
    """(training, validation) partitions: a seeded ``fraction`` of them held out."""
    bounds = partition_bounds(n, size)
    if len(bounds) < 2:
        raise BTFInputError(
            f"learning tau holds out whole partitions of {size} training points, but the "
            f"{n} training points make {len(bounds)}; train on at least {size + 1} points"
        )
    n_val = min(len(bounds) - 1, max(1, round(fraction * len(bounds))))
    val = set(np.random.default_rng(seed).choice(len(bounds), n_val, replace=False).tolist())
    return ([b for i, b in enumerate(bounds) if i not in val],
            [b for i, b in enumerate(bounds) if i in val])  # fmt: skip


def validation_errors(source: Any, ranges: list[tuple[int, int]], pool: list[list[np.ndarray]],
                      grid: list[int], dtype: type, batch_size: int) -> np.ndarray:  # fmt: skip
    """(n_val, J, C) error per entry of each held-out point on each pool dictionary (``pool``:
    per dictionary its N mode bases) at each coding level of ``grid`` (the least-error
    coding at τ_c, by Parseval)."""
    size = int(np.prod(source.mode_sizes))
    taus = [min(int(t), size) for t in grid]
    top = max(taus)
    mats = [[np.asarray(u, dtype=dtype) for u in d] for d in pool]

    def one(x: np.ndarray) -> np.ndarray:
        energy = float(np.sum(np.square(x, dtype=np.float64)))
        out = np.empty((len(mats), len(taus)))
        for j, m in enumerate(mats):
            s = project(np.asarray(x, dtype=dtype)[None], m)[0].reshape(-1)
            kept = np.cumsum(np.square(s[topk_abs(s, top)], dtype=np.float64))
            out[j] = [max(energy - kept[t - 1], 0.0) / size for t in taus]
        return out

    rows: list[np.ndarray] = []
    for lo, hi in ranges:
        for _, xb in part_of(source, lo, hi).batches(batch_size):
            rows += list(parallel_map(one, list(np.asarray(xb))))
    return np.stack(rows)


def forward_selection(err: np.ndarray, k: int) -> tuple[list[int], list[float]]:
    """K pool indices chosen greedily (module docstring, step 4) and the score after each."""
    chosen: list[int] = []
    scores: list[float] = []
    best = np.full(err.shape[::2], np.inf)  # (n_val, C)
    for _ in range(min(k, err.shape[1])):
        cand = [j for j in range(err.shape[1]) if j not in chosen]
        vals = [float(np.mean(np.log(np.maximum(np.minimum(best, err[:, j]).mean(axis=0),
                                                1e-300)))) for j in cand]  # fmt: skip
        pick = cand[int(np.argmin(vals))]
        chosen.append(pick)
        scores.append(min(vals))
        best = np.minimum(best, err[:, pick])
    return chosen, scores


def fit_levels(est: Any, src: Any, desc: str, executor: Any,
               partition: Callable[[int, int, int], Any] | None, data_key: str) -> Any:  # fmt: skip
    """Fit ``est`` (a :class:`~.ensemble.DictionaryEnsemble` with several τ_l or
    ``learn_tau``) level by level (module docstring); sets its fitted attributes."""
    t0 = time.perf_counter()
    levels = est.levels
    check_layout(est.checkpoint, several=True)
    key: dict[str, Any] = {"levels": levels, "learn_tau": bool(est.learn_tau)}
    train_src, sub_partition, per_level = src, partition, est.n_dictionaries // len(levels)
    val_ranges: list[tuple[int, int]] = []
    if est.learn_tau:
        key["validation"] = est.validation
        train_ranges, val_ranges = _split(src.n_points, est.partition_size, est.validation,
                                          est.random_state + SPLIT_SEED)  # fmt: skip
        train_src, per_level = PartsSource(src, train_ranges), est.n_dictionaries
        if partition is not None:
            size = est.partition_size

            def sub_partition(lo: int, hi: int, slot: int) -> Any:  # partitions stay whole
                return partition(*train_ranges[lo // size], slot)

    fits = []
    for lv, tau in enumerate(levels):
        ck = None if est.checkpoint is None else level_checkpoint(est.checkpoint, lv)
        sub = est.level_estimator(tau, per_level, est.random_state + LEVEL_SEED * lv, ck,
                                  {**key, "level": lv})  # fmt: skip
        fits.append(sub.fit(train_src, f"{desc} tau{tau}", executor=executor,
                            partition=sub_partition, data_key=data_key))  # fmt: skip
    pool = [(lv, j) for lv in range(len(levels)) for j in range(fits[lv].counts_.size)]
    est.validation_ = None
    if est.learn_tau:
        dicts = [[d[j] for d in fits[lv].dictionaries_] for lv, j in pool]
        coding = [int(t) for t in est.validation_taus or levels]
        err = validation_errors(src, val_ranges, dicts, coding, np.dtype(est.dtype).type,
                                est.batch_size)  # fmt: skip
        picked, scores = forward_selection(err, est.n_dictionaries)
        chosen = [pool[j] for j in picked]
        est.validation_ = {
            "grid": levels, "coding_taus": coding, "points": int(err.shape[0]), "chosen_levels":
            [levels[lv] for lv, _ in chosen], "scores": scores,
            "level_errors": err.min(axis=1).mean(axis=0).tolist() if err.size else [],
        }  # fmt: skip
    else:
        chosen = pool
    _assemble(est, fits, chosen, levels)
    est.mode_sizes_ = src.mode_sizes
    est.fit_seconds_ = time.perf_counter() - t0
    return est


def _assemble(est: Any, fits: list[Any], chosen: list[tuple[int, int]], levels: list[int]
              ) -> None:  # fmt: skip
    """The chosen dictionaries of the level fits as one ensemble, with their diagnostics."""
    n_modes = len(fits[0].dictionaries_)
    est.dictionaries_ = [np.stack([fits[lv].dictionaries_[m][j] for lv, j in chosen])
                         for m in range(n_modes)]  # fmt: skip
    est.taus_ = [levels[lv] for lv, _ in chosen]
    pos = {c: i for i, c in enumerate(chosen)}
    est.membership_ = np.stack([
        np.array([pos.get((lv, int(j)), -1) for j in f.membership_]) for lv, f in enumerate(fits)
    ], axis=1)  # fmt: skip
    est.counts_ = np.array([int(fits[lv].counts_[j]) for lv, j in chosen])
    longest = max(len(f.objective_) for f in fits)
    # one value per iteration: the levels' mean (a level that stopped early keeps its last)
    est.objective_ = [float(np.mean([f.objective_[min(i, len(f.objective_) - 1)] for f in fits]))
                      for i in range(longest)]  # fmt: skip
    est.passes_ = next(f.passes_ for f in fits if len(f.objective_) == longest)
    est.candidates_ = max(f.candidates_ for f in fits)
    est.n_iter_ = max(f.n_iter_ for f in fits)
    est.iteration_seconds_ = [s for f in fits for s in f.iteration_seconds_]
    est.iteration_cpu_seconds_ = [s for f in fits for s in f.iteration_cpu_seconds_]
    est.levels_ = [{"tau": levels[lv], "objective": [float(v) for v in f.objective_],
                    "n_iter": int(f.n_iter_), "seconds": float(f.fit_seconds_),
                    "membership_counts": [int(c) for c in f.counts_]}
                   for lv, f in enumerate(fits)]  # fmt: skip

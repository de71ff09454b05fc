"""What a training run carries from one iteration to the next, and checks on a resumed one.

:class:`TrainState` is what :class:`~.ensemble.DictionaryEnsemble` keeps between iterations
and writes to its checkpoints; :func:`check_state` is what a checkpoint's counters must say;
:func:`with_extra` and :func:`keep_current` manage the candidate lists of the partial passes.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..errors import FileFormatError

__all__ = ["TRAIN_FIELDS", "TrainState", "check_state", "keep_current", "with_extra"]


@dataclass
class TrainState:
    """What an iteration carries to the next (and a checkpoint stores)."""

    dicts: list[np.ndarray]
    objective: list[float]
    passes: list[str]  # "full" or "partial", one per objective value
    iteration: int
    ranking: np.ndarray | None = None  # (N, c) candidates from the last full pass
    reseeded_from: list[int] = field(default_factory=list)
    converged: bool = False  # met the tolerance: a resumed fit runs no more iterations


def check_state(state: TrainState, n_points: int, k: int, where: str) -> None:
    """What a checkpoint's counters must say: one objective value (finite, >= 0) and one
    pass label per iteration plus the initial coding, candidates and re-seeds in range."""
    n = len(state.objective)
    ok_obj = all(np.isfinite(v) and v >= 0 for v in state.objective)
    if state.iteration < 0 or n != state.iteration + 1 or len(state.passes) != n or not ok_obj:
        raise FileFormatError(
            f"{where}: iteration {state.iteration} with {n} objective values "
            f"{state.objective[:3]} and {len(state.passes)} passes; expected iteration + 1 "
            "finite objective values >= 0 and as many passes"
        )
    if any(p not in ("full", "partial") for p in state.passes):
        raise FileFormatError(f"{where}: passes {state.passes[:4]}; expected 'full' or 'partial'")
    r = state.ranking
    if r is None or r.ndim != 2 or r.shape[0] != n_points or r.dtype.kind not in "iu" or (
        r.size and (int(r.min()) < 0 or int(r.max()) >= k)
    ):
        found = "nothing" if r is None else f"{r.dtype} {r.shape}"
        raise FileFormatError(
            f"{where}: ranking is {found}; expected ({n_points}, c) dictionary indices in [0, {k})"
        )
    if any(not 0 <= i < n_points for i in state.reseeded_from):
        raise FileFormatError(
            f"{where}: reseeded_from {state.reseeded_from[:4]}; expected point indices in "
            f"[0, {n_points})"
        )


#: The arrays every training checkpoint holds (besides ``sha256`` and the dictionaries).
TRAIN_FIELDS = ("iteration", "objective", "passes", "ranking", "reseeded_from", "converged",
                "key")  # fmt: skip


def with_extra(ranking: np.ndarray, extra: list[int]) -> np.ndarray:
    """Each point's candidates plus dictionaries every point must try (re-seeded ones)."""
    if not extra:
        return ranking
    return np.column_stack([ranking, np.broadcast_to(np.array(extra), (len(ranking), len(extra)))])


def keep_current(ranking: np.ndarray, membership: np.ndarray) -> None:
    """Put a point's dictionary among its candidates when a partial pass moved it to one
    outside them (a re-seeded one), in place of its last: the current dictionary is always
    tried, so the objective cannot increase."""
    missing = ~(ranking == membership[:, None]).any(axis=1)
    ranking[missing, -1] = membership[missing]

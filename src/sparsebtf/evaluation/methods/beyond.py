"""Training variants beyond the paper (issue 34), coded exactly like the reference.

Each trains its own ensemble on the benchmark's training materials, with the reference's K,
sample, iterations and tolerance, and codes every material at each level with the
reference's fixed τ (so at exactly its bytes: the same coefficients per point, the same
accounting); only the training differs:

* :class:`MultiTauMethod` (``sparsebtf-multitau``): the K dictionaries split over several τ_l
  (:func:`multitau_levels`), each trained at its own (:mod:`sparsebtf.learning.tau_levels`).
* :class:`LearnTauMethod` (``sparsebtf-learntau``): each dictionary's τ_l chosen from the grid
  (τ_l/4, τ_l, the higher level of :func:`multitau_levels`) by the error on a validation
  fifth of the training points, measured at the τ_t the benchmark codes its levels at
  (three fits of K: about 3x the reference's training).
* :class:`PreclusterMethod` (``sparsebtf-precluster``): ``init="preclustered"``
  (:mod:`sparsebtf.learning.init`).

The verdicts on them are :mod:`sparsebtf.evaluation.training_verdicts`'.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, ClassVar

from ...data.btf import BTF
from ...learning.codes import RELEASE_TAU, RELEASE_TAU_TRAIN
from ...learning.partitions import PARTITION_POINTS
from .base import FitContext, Method
from .sparse import _Ensemble

__all__ = ["LearnTauMethod", "MultiTauMethod", "PreclusterMethod", "multitau_levels"]


def _higher(tau: tuple[int, ...]) -> tuple[int, ...]:
    """The level above τ_l: the release's coded τ 885,64,64 relative to the paper's 256,32,32
    (Y × 885/256, chroma × 2)."""
    (y, c), (ty, tc) = RELEASE_TAU[:2], RELEASE_TAU_TRAIN[:2]
    return (round(tau[0] * y / ty), *(round(t * c / tc) for t in tau[1:]))


def multitau_levels(tau: tuple[int, ...], k: int) -> list[tuple[int, ...]]:
    """The levels of ``sparsebtf-multitau`` for K dictionaries and the reference's τ_l.

    K even: (τ_l, the level above, :func:`_higher`): every τ_t the benchmark codes is >= τ_l
    (levels 16–128: Y from 326 to 4,478 at 400x400), so the added level is the one nearer the
    coded τ_t; K a multiple of 3 but odd: (τ_l/4, τ_l, the level above); otherwise τ_l alone
    (the reference's training).
    """
    tau = tuple(int(t) for t in tau)
    if k % 2 == 0:
        return [tau, _higher(tau)]
    if k % 3 == 0:
        return [tuple(max(1, t // 4) for t in tau), tau, _higher(tau)]
    return [tau]


class MultiTauMethod(_Ensemble):
    """The reference's ensemble with its K dictionaries trained at several τ_l."""

    name = "sparsebtf-multitau"
    label = "SparseBTF, several tau_l"

    def train_tau(self) -> Any:  # type: ignore[override]
        levels = multitau_levels(self.tau_train, self.n_dictionaries)
        return levels if len(levels) > 1 else levels[0]


class LearnTauMethod(_Ensemble):
    """The reference's ensemble with each dictionary's τ_l learned on a validation split."""

    name = "sparsebtf-learntau"
    label = "SparseBTF, learned tau_l"

    def train_tau(self) -> Any:  # type: ignore[override]
        t = tuple(int(v) for v in self.tau_train)
        grid = [tuple(max(1, v // 4) for v in t), t, _higher(t)]
        # each level once (a tiny τ_l's quarter can round to itself)
        return "learn:" + "/".join(dict.fromkeys(",".join(map(str, lv)) for lv in grid))

    def fit(self, train_btfs: Sequence[BTF], context: FitContext) -> Method:
        # The validation split holds out whole partitions (5 at least, so a fifth is one):
        # small training sets (the tests' configuration) get smaller partitions.
        n = sum(int(self.sample * (b.height // self.patch) * (b.width // self.patch))
                for b in train_btfs)  # fmt: skip
        size = PARTITION_POINTS if n >= 5 * PARTITION_POINTS else max(1, n // 5)
        # the validation error at the τ_t the benchmark codes every level at
        coded = [self.level_tau(train_btfs[0], lv) for lv in sorted(self.level_ratios)]
        self.training_options = {**type(self).training_options, "partition_size": size,
                                 "tau_validation": "/".join(dict.fromkeys(
                                     ",".join(map(str, t)) for t in coded))}  # fmt: skip
        return super().fit(train_btfs, context)

    def describe(self) -> dict[str, Any]:
        return {**super().describe(), "tau_train_used": self.train_tau()}


class PreclusterMethod(_Ensemble):
    """The reference's ensemble started from pre-clustered dictionaries."""

    name = "sparsebtf-precluster"
    label = "SparseBTF, pre-clustered"
    training_options: ClassVar[dict[str, Any]] = {"std_mode": "shared", "init": "preclustered"}

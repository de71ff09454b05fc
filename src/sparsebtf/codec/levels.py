"""The training sparsities of a model: one τ_l per channel (the paper), several levels, or
``learn`` (beyond the paper, :mod:`sparsebtf.learning.tau_levels`).

Spellings (CLI ``--tau-train`` and :func:`~sparsebtf.codec.train.train`'s ``tau_train``):

* one level: ``"256,32,32"``, ``(256, 32, 32)``, ``256``, ``{"Y": 256, ...}`` (as before);
* several levels, the K dictionaries split evenly over them: ``"64,8,8/256,32,32/885,64,64"``
  or ``[(64, 8, 8), (256, 32, 32), (885, 64, 64)]``;
* ``"learn"``: each dictionary's τ_l chosen from the grid :data:`LEARN_GRID` by the error on a
  validation split; ``"learn:64,8,8/256,32,32"`` names the grid.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from ..errors import BTFInputError
from ..learning.codes import RELEASE_TAU, RELEASE_TAU_TRAIN
from ..model import TauSpec, parse_tau

__all__ = ["LEARN", "LEARN_GRID", "TauTrainSpec", "parse_tau_train"]

#: The spelling of learned levels.
LEARN = "learn"
#: The candidate grid of ``"learn"`` (Y, U, V per level): a quarter of the paper's τ_l, the
#: paper's τ_l, and the release's coded τ_t 885,64,64.
LEARN_GRID = (tuple(t // 4 for t in RELEASE_TAU_TRAIN), RELEASE_TAU_TRAIN, RELEASE_TAU)

#: What ``tau_train`` can be: one level (:data:`~sparsebtf.model.TauSpec`), a sequence of
#: levels, or ``"learn"`` / ``"learn:LEVELS"``.
TauTrainSpec = TauSpec | Sequence[TauSpec]


def _is_level_list(tau: Any) -> bool:
    return (isinstance(tau, Sequence) and not isinstance(tau, str) and len(tau) > 0
            and all((isinstance(t, (Sequence, Mapping)) and not isinstance(t, str)) or
                    (isinstance(t, str) and "," in t) for t in tau))  # fmt: skip


def parse_tau_train(tau_train: TauTrainSpec, channels: Sequence[str]
                    ) -> tuple[dict[str, list[int]], bool]:  # fmt: skip
    """(levels per channel, learn): every channel's training sparsities, in the order given,
    and whether they are a grid to learn from. One clear line for a bad spelling."""
    learn = False
    tau: Any = tau_train
    if isinstance(tau, str) and tau.strip().lower().startswith(LEARN):
        learn = True
        rest = tau.strip()[len(LEARN):]
        if rest and not rest.startswith(":"):
            raise BTFInputError(f"tau_train {tau_train!r}: expected 'learn' or "
                                "'learn:LEVELS' such as 'learn:64,8,8/256,32,32'")
        tau = rest[1:] if rest else (
            [sum(t) for t in LEARN_GRID] if len(channels) == 1 else list(LEARN_GRID))
    if isinstance(tau, str) and "/" in tau:
        tau = [p.strip() for p in tau.split("/")]
    if isinstance(tau, str) and learn and "," not in tau:
        tau = [tau]
    levels = list(tau) if _is_level_list(tau) or (learn and isinstance(tau, list)) else [tau]
    per_level = [parse_tau(t, channels) for t in levels]
    seen = set()
    for lv in per_level:  # a level twice trains the same dictionaries twice: adds nothing
        key = tuple(lv[ch] for ch in channels)
        if key in seen:
            raise BTFInputError(f"{tau_train!r}: the level {','.join(map(str, key))} is given "
                                "twice; give each level once")  # fmt: skip
        seen.add(key)
    out = {ch: [lv[ch] for lv in per_level] for ch in channels}
    if learn and len(levels) < 2:
        raise BTFInputError(f"tau_train {tau_train!r}: learning tau needs a grid of at least "
                            "two levels, such as 'learn:64,8,8/256,32,32'")
    return out, learn

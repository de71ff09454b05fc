"""Training until convergence: the stop rule every neural baseline trains under.

A baseline is a competitor: it trains until its loss on **held-out queries** of the material
(queries that are not in its training pool, :class:`~._torch.HeldOut`) stops improving, not
for a fixed number of steps. The rule, :class:`StopRule`:

* the held-out loss ``h`` is measured every ``eval_every`` queries per texel;
* at step t, the phase has *plateaued* when the best held-out loss up to now improved by less
  than ``tolerance`` (relative) on the best up to step ``(1 − window)·t`` — "less than 1 %
  over the last fifth of its steps" — and that last fifth lies after the last learning-rate
  drop (so each phase runs at least a quarter longer than all before it);
* on a plateau the learning rate drops by ``lr_drop`` (to at least the schedule's floor);
  a plateau at the floor ends training with ``converged = True``;
* the cap (``max_queries_per_texel``, ``max_seconds``) ends it with ``converged = False``.

Learning rates adapt to the run: a wider first layer (a larger latent) that needs a smaller
step gets it from the drops, instead of from a schedule fixed in advance for every size.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from ..._progress import bar

__all__ = ["StopRule", "plateaued", "train_to_convergence"]


@dataclass(frozen=True)
class StopRule:
    """When a neural training stops (module docstring).

    ``max_queries_per_texel`` is the cap of training queries seen per texel, ``max_seconds``
    a cap of CPU seconds (None: none), ``min_queries_per_texel`` the effort before the rule is
    tested at all (NeuMIP: until its texture blur has faded), ``eval_every`` the queries per
    texel between two held-out evaluations.
    """

    max_queries_per_texel: float
    eval_every: float
    tolerance: float = 0.01
    window: float = 0.2
    lr_drop: float = 0.3
    min_queries_per_texel: float = 0.0
    max_seconds: float | None = None

    def __post_init__(self) -> None:
        if not (self.max_queries_per_texel > 0 and self.eval_every > 0):
            raise ValueError(f"max_queries_per_texel and eval_every must be > 0, got "
                             f"{self.max_queries_per_texel} and {self.eval_every}")  # fmt: skip
        if not (0 < self.window < 1 and 0 < self.lr_drop < 1 and self.tolerance >= 0):
            raise ValueError(f"window and lr_drop must lie in (0, 1) and tolerance >= 0, got "
                             f"{self.window}, {self.lr_drop}, {self.tolerance}")  # fmt: skip

    def scaled(self, factor: float) -> StopRule:
        """The same rule with its cap, minimum and evaluation spacing times ``factor``."""
        return StopRule(self.max_queries_per_texel * factor, self.eval_every * factor,
                        self.tolerance, self.window, self.lr_drop,
                        self.min_queries_per_texel * factor, self.max_seconds)  # fmt: skip

    def describe(self) -> dict[str, Any]:
        return dict(vars(self))


def plateaued(curve: Sequence[tuple[float, float]], since: float, rule: StopRule) -> bool:
    """Whether the held-out ``curve`` [(effort, loss), …] has stopped improving: its best loss
    improved by less than ``rule.tolerance`` over the last ``rule.window`` of the effort, and
    that last part starts at or after ``since`` (the last learning-rate drop) and after
    ``rule.min_queries_per_texel``."""
    if not curve:
        return False
    now = curve[-1][0]
    start = (1 - rule.window) * now
    if start < since or now < rule.min_queries_per_texel:
        return False
    before = [h for q, h in curve if q <= start]
    if not before:
        return False
    old, best = min(before), min(h for _, h in curve)
    if not (math.isfinite(old) and math.isfinite(best)):
        return not math.isfinite(best)  # diverged: nothing left to gain at this rate
    return best > (1 - rule.tolerance) * old


def train_to_convergence(
    params: Sequence[torch.Tensor],
    loss_at: Callable[[int, float], torch.Tensor],
    heldout: Callable[[], float],
    queries_per_step: float,
    lr: tuple[float, float],
    rule: StopRule,
    desc: str,
    progress: bool | None,
    lazy: bool | None = None,
) -> dict[str, Any]:
    """Adam on ``loss_at(step, queries_per_texel_so_far)`` until ``rule`` says stop.

    ``queries_per_step`` is the training queries per texel one step adds; ``heldout()`` the
    loss on the held-out queries (evaluated without gradients); ``lr`` (first, floor). Returns
    ``converged``, ``loss_curve`` [(queries per texel, held-out loss)], ``iterations``,
    ``queries_per_texel``, ``cpu_seconds``, ``lr_drops`` (the efforts they happened at),
    ``heldout_loss`` (final) and the mean training loss of the first and last tenth of steps.
    It runs where ``params`` are (their device); ``cpu_seconds`` is this process's CPU time,
    on a GPU too. ``lazy``: read the training losses at each evaluation instead of after every
    step (the same numbers; None: on a GPU, where a read waits for the device).
    """
    t_cpu = time.process_time()
    params = list(params)
    opt = torch.optim.Adam(params, lr=lr[0])
    # on a GPU the training losses are read at each evaluation, not after every step (a
    # read waits for the device); on the CPU each is read when it is computed, as always
    if lazy is None:
        lazy = bool(params) and params[0].device.type != "cpu"
    pending: list[torch.Tensor] = []
    rate, floor = float(lr[0]), float(min(lr))
    max_steps = max(1, math.ceil(rule.max_queries_per_texel / queries_per_step))
    every = max(1, round(rule.eval_every / queries_per_step))
    losses: list[float] = []
    curve: list[tuple[float, float]] = []
    drops: list[float] = []
    since, converged, step = 0.0, False, 0

    def evaluate() -> None:
        if pending:
            losses.extend(torch.stack(pending).tolist())
            pending.clear()
        with torch.no_grad():
            h = float(heldout())
            curve.append((round(step * queries_per_step, 3), h if math.isfinite(h) else math.inf))

    evaluate()
    with bar(max_steps, desc, "step", progress) as pb:
        while step < max_steps:
            opt.zero_grad(set_to_none=True)
            loss = loss_at(step, step * queries_per_step)
            loss.backward()
            opt.step()
            if lazy:
                pending.append(loss.detach())
            else:
                losses.append(float(loss.detach()))
            step += 1
            pb.update(1)
            if step % every and step < max_steps:
                continue
            evaluate()
            if plateaued(curve, since, rule):
                if rate <= floor * (1 + 1e-9):
                    converged = True
                    break
                rate = max(rate * rule.lr_drop, floor)
                for group in opt.param_groups:
                    group["lr"] = rate
                since = curve[-1][0]
                drops.append(since)
            if rule.max_seconds is not None and time.process_time() - t_cpu > rule.max_seconds:
                break
    if pending:
        losses.extend(torch.stack(pending).tolist())
    k = max(1, len(losses) // 10)
    arr = np.asarray(losses)
    return {"converged": converged, "loss_curve": [list(p) for p in curve],
            "iterations": step, "queries_per_texel": round(step * queries_per_step, 3),
            "cpu_seconds": round(time.process_time() - t_cpu, 3), "lr_drops": drops,
            "heldout_loss": curve[-1][1], "stop_rule": rule.describe(),
            "loss_first": float(arr[:k].mean()), "loss_last": float(arr[-k:].mean())}  # fmt: skip

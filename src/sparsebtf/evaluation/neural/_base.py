"""What the three neural methods share as :class:`~..methods.base.Method` subclasses: the
seed, threads, device, progress and training-budget bookkeeping, the size search under a byte budget
and the :class:`~..methods.base.Coding` they return."""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any

import torch

from ...data.btf import BTF
from ..methods.base import Budget, Coding, FitContext, Method
from ._torch import NeuralBTF, check_device, mlp_params, resolve_device

__all__ = ["NeuralMethod", "largest_size"]


def largest_size(budget_bytes: int, texels: int, sizes: Callable[[int], list[int]],
                 stored_decoder: bool) -> int:  # fmt: skip
    """The largest n with 2·texels·n + 2·(decoder parameters at n) <= ``budget_bytes``
    (binary16 values; the decoder term only when ``stored_decoder``), or 0 if none.

    ``sizes(n)`` gives the decoder's widths when each texel stores n values; its parameter
    count is affine in n (n enters the first layer only), p(n) = p(0) + n·(p(1) − p(0)), so
    n = ⌊(budget/2 − p(0)) / (texels + p(1) − p(0))⌋.
    """
    p0 = mlp_params(sizes(0)) if stored_decoder else 0
    per_n = (mlp_params(sizes(1)) if stored_decoder else 0) - p0
    n = math.floor((budget_bytes / 2 - p0) / (texels + per_n))
    return max(n, 0)


class NeuralMethod(Method):
    """Base of the neural baselines: ``seed`` (None: the run's ``FitContext.seed``),
    ``threads`` (torch intra-op threads on the CPU; None: :func:`~._torch.default_threads`),
    ``device`` (``"cpu"``, ``"cuda"``, ``"cuda:N"``, ``"auto"``; None: ``$SPARSEBTF_TORCH_DEVICE``
    where the method runs, else the CPU; :func:`~._torch.resolve_device`), ``progress``; the
    training cost accumulates in ``seconds_`` (wall), ``cpu_seconds_`` and ``trainings_``, of
    which ``trainings_converged_`` stopped on their held-out plateau (:mod:`._convergence`)."""

    #: (for a method pickled before devices existed)
    device: str | None = None

    def __init__(self, seed: int | None = None, threads: int | None = None,
                 progress: bool | None = None, device: str | None = None) -> None:  # fmt: skip
        self.seed = seed
        self.threads = threads
        self.progress = progress
        self.device = check_device(device)
        self.seconds_ = 0.0
        self.cpu_seconds_ = 0.0
        self.trainings_ = 0
        self.trainings_converged_ = 0
        self.efforts_: list[float] = []
        self.log_: list[tuple[float, dict[str, Any], str]] = []
        self._run_seed = 0

    def record(self, seconds: float, fit: dict[str, Any], kind: str = "train") -> None:
        """Add one training's wall seconds and its :func:`~._convergence.train_to_convergence`
        record (CPU seconds, whether it converged) to the method's totals and its
        :meth:`cost_log`; ``kind`` tells a subclass's other trainings apart (fine-tuning)."""
        self.log_.append((seconds, fit, kind))
        self._count(seconds, fit, kind)

    def _count(self, seconds: float, fit: dict[str, Any], kind: str) -> None:
        self.seconds_ += seconds
        self.cpu_seconds_ += float(fit.get("cpu_seconds", 0.0))
        self.trainings_ += 1
        self.trainings_converged_ += bool(fit.get("converged"))
        self.efforts_.append(float(fit.get("queries_per_texel", 0.0)))

    def cost_log(self) -> list[Any]:
        return self.log_

    def replay(self, entries: Sequence[Any]) -> None:
        for seconds, fit, kind in entries:
            self.record(seconds, fit, kind)

    def effort_summary(self) -> dict[str, Any]:
        """The trainings' effort for ``training_budget``: CPU seconds, how many converged,
        the training queries per texel they used (least, most)."""
        return {"cpu_seconds": round(self.cpu_seconds_, 3), "trainings": self.trainings_,
                "converged": self.converged_,
                "queries_per_texel": round(max(self.efforts_), 1) if self.efforts_ else 0,
                "queries_per_texel_min": round(min(self.efforts_), 1) if self.efforts_ else 0}

    @property
    def converged_(self) -> str:
        """How many of the method's trainings converged, as ``"k/n"``."""
        return f"{self.trainings_converged_}/{self.trainings_}"

    def fit(self, train: Sequence[BTF], context: FitContext) -> NeuralMethod:
        self._run_seed = int(context.seed)
        if self.progress is None and context.progress is not None:
            self.progress = context.progress
        return self

    @property
    def device_(self) -> torch.device:
        """The device the method trains and decodes on, resolved where it runs (a Dask
        worker reads its own ``$SPARSEBTF_TORCH_DEVICE`` when ``device`` is None)."""
        return resolve_device(self.device)

    @staticmethod
    def config_device(config: Any) -> str | None:
        """The device a benchmark configuration asks for (``BenchConfig.torch_device``)."""
        return getattr(config, "torch_device", None)

    @property
    def seed_(self) -> int:
        """The seed in use: the method's own, else the run's."""
        return self._run_seed if self.seed is None else int(self.seed)

    def describe(self) -> dict[str, Any]:
        out = super().describe()
        recipe = getattr(self, "recipe", None)
        if recipe is not None:
            out["recipe"] = {k: (list(v) if isinstance(v, tuple) else v)
                             for k, v in vars(recipe).items()}  # fmt: skip
        return out

    @staticmethod
    def coding(rec: NeuralBTF, budget: Budget, shared_decoder: bool,
               info: dict[str, Any]) -> Coding:  # fmt: skip
        """The coding of ``rec``: its bytes counted from its stored binary16 arrays (the code,
        and the decoder too unless ``shared_decoder``)."""
        code_bytes = 2 * rec.code.size
        decoder_bytes = 2 * rec.decoder_values()
        material = code_bytes + (0 if shared_decoder else decoder_bytes)
        full = {"matching": budget.matching, "level": budget.level,
                "budget_bytes": budget.material_bytes, "code_bytes": code_bytes,
                "decoder_bytes": decoder_bytes, "decoder_shared": shared_decoder,
                "decoder_params": rec.decoder_values(), "device": str(rec.device),
                **info}  # fmt: skip
        return Coding(rec, material, decoder_bytes if shared_decoder else 0, full)

    @staticmethod
    def nothing_fits(budget: Budget, why: str) -> Coding:
        return Coding(None, 0, 0, {"matching": budget.matching, "level": budget.level,
                                   "budget_bytes": budget.material_bytes}, note=why)  # fmt: skip

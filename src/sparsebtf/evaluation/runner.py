"""``sparsebtf bench quality``: the paper's comparative evaluation on our benchmark.

Pipeline (every number lands in ``results.json``; :mod:`.report` turns it into tables, plots
and ``results.md``). The compared methods are :class:`~.methods.Method` objects
(:mod:`.methods`; the defaults: SparseBTF, rate control, per-channel standardisation,
[MHU19], per-material PCA in the log and linear domain, and the neural encodings when PyTorch
is installed); the runner knows only their interface:

1. materials of :class:`~.benchmark_set.BenchConfig` (synthetic, cached) plus ``--materials``;
2. every method is fitted (:meth:`~.methods.Method.fit`): the reference, SparseBTF, first
   (its model's per-material bytes define everyone's budgets), then the others;
3. per test material the reference codes every storage level with a fixed τ per point
   (ε = 0, so every point holds exactly τ coefficients as in the paper's tables) plus the
   extra τ_t of the Figure 3 curves; every other method codes at :class:`~.methods.Budget`
   built from the reference's bytes, once per matching it declares: ``per_material``
   (SparseBTF(L)'s per-material bytes on this material) and ``paper`` (2·L·H·W: L binary16
   values per texel); every row names its ``matching``;
4. the Table 5 materials (100 × 100 texels) coded by the reference and by the methods that
   code that set (per-material PCA at 1× and 2× SparseBTF's bytes);
5. true-black materials (exact zeros, high dynamic range; ``BenchConfig.black_materials``)
   coded by the reference at every level with the configured log offset, with the release's
   1e-5, and as a copy floored at 1e-3, all scored against the unfloored material;
6. MSE (linear RGB, the paper's tables), display-mapped MSE, log MSE, PSNR and SSIM for every
   reconstruction (:func:`~.scoring.score_many`: one pass over each material for all its
   reconstructions, each decoded once; the standardised-domain MSE of the coded ones by
   Parseval from their coefficients), the largest decoded value and the worst 0.01 %'s share
   of the error, image grids like Figures 4 and 5.

Bytes are the paper's Table 4 accounting per material (:mod:`.methods.sparse`,
:mod:`.methods.pca`); shared parts (dictionaries, a shared decoder) are reported once per
method, never in the per-material bytes.

The steps themselves are in :mod:`.stages` and :mod:`.figure_stages`; this module runs them in
turn, checkpoints each material to resume from (:mod:`.resume`) and writes the results.
"""

from __future__ import annotations

import itertools
import json
import os
import platform
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np

from .._atomic import atomic_output
from .._json import json_default
from .._version import library_version
from ..execution import Executor, executor
from .benchmark_set import BenchConfig

# the stages' public names, this module's until they moved, stay importable from here
from .figure_stages import (
    FIGURE5,  # noqa: F401
    _FigureStages,
)
from .methods import Method
from .methods.selection import resolve_methods
from .stages import (
    METHODS,
    METRICS,  # noqa: F401
    VARIANTS,
    _label,
    _Stages,
    budgets_for,  # noqa: F401
    floored,  # noqa: F401
    method_row,  # noqa: F401
)

__all__ = ["METHODS", "VARIANTS", "run_quality"]


class _Log:
    def __init__(self, fn: Callable[[str], None]) -> None:
        self.fn = fn
        self.t0 = time.perf_counter()

    def __call__(self, msg: str) -> None:
        self.fn(f"[{time.perf_counter() - self.t0:7.1f} s] {msg}")


def run_quality(
    out: str | os.PathLike[str],
    config: BenchConfig | None = None,
    *,
    materials: Sequence[str] = (),
    seed: int = 0,
    log: Callable[[str], None] = print,
    progress: bool | None = None,
    previous: str | os.PathLike[str] | None = None,
    client: Any = None,
    scheduler: str | None = None,
    workers: int | None = None,
    methods: Sequence[str | type[Method]] | None = None,
    resume: bool = False,
) -> dict[str, Any]:
    """Run the benchmark into folder ``out``; returns (and writes) the results object.

    ``materials`` are extra test BTFs (any source :func:`~sparsebtf.open.open_btf`
    accepts: ``.btf``, dense ``.h5``, ``synth:…``); they need the benchmark's directions and
    a size that is a multiple of the patch. ``seed`` shifts every material seed and the
    training seed. ``previous`` (an earlier run's ``results.json``) adds how each verdict
    moved from it. ``client`` / ``scheduler`` / ``workers`` run its training and encoding on a
    Dask cluster (:func:`sparsebtf.execution.executor`; the results do not change).
    ``methods``: registry names, groups, ``"package.module:Class"`` or
    :class:`~.methods.Method` subclasses (default: :func:`~.methods.selection.default_methods`);
    the reference, SparseBTF, is always run. ``resume``: continue the interrupted run whose
    checkpoints ``out/partial`` holds (:mod:`.resume`; without it such a folder is refused).
    """
    with executor(client=client, scheduler=scheduler, workers=workers) as ex:
        return _QualityRun(config, seed, log, progress, ex, methods).run(
            out, materials, previous, resume
        )


class _QualityRun(_Stages, _FigureStages):
    """One run's state: configuration, methods, rows, timings."""

    def __init__(self, config: BenchConfig | None, seed: int, log: Callable[[str], None],
                 progress: bool | None, ex: Executor,
                 methods: Sequence[str | type[Method]] | None) -> None:  # fmt: skip
        self.cfg = (config or BenchConfig()).with_seed(seed)
        self.seed = seed
        self.say = _Log(log)
        self.progress = progress
        self.ex = ex
        from .methods.sparse import OBJECTIVE_METHODS, objective_variant

        classes = resolve_methods(methods, self.cfg, note=self.say)
        self.methods = [cls.from_config(self.cfg) for cls in classes]
        # each further coding objective codes the reference and rate control again, with
        # their models (rows sparsebtf-<objective>, rate-<objective>)
        self.methods += [objective_variant(m, o) for o in tuple(self.cfg.objectives)[1:]
                         for m in self.methods if m.name in OBJECTIVE_METHODS]  # fmt: skip
        self.adopt(self.methods)
        self.rows: list[dict[str, Any]] = []
        self.values: dict[str, dict[str, Any]] = {}
        self.grids: list[str] = []
        self.timings: dict[str, float] = {}
        self.out = Path(".")
        self.figure5: list[str] = []
        self.figure8: dict[str, Any] = {}
        self.speed: dict[str, Any] = {}
        self._remote_methods: dict[str, Any] = {}

    def adopt(self, methods: list[Method]) -> None:
        """The run's methods (built, or loaded from a checkpoint), the reference first."""
        self.methods = methods
        self.ref: Any = methods[0]
        #: the reference and its objective variants, with their rows' name suffix
        self.coders = [(self.ref, "")] + [(m, f"-{m.objective}") for m in methods
                                          if getattr(m, "base_", None) is self.ref]
        self.others = methods[1:]

    def elapsed(self) -> float:
        return time.perf_counter() - self.t_start

    def stage(self, name: str, t0: float) -> None:
        self.timings[name] = self.timings.get(name, 0.0) + time.perf_counter() - t0


    # -- checkpoints ----------------------------------------------------------------------------
    def done(self, index: int) -> bool:
        """Material ``index`` (of the run's order) restored from its checkpoint, if any."""
        rec = self.store.material(index) if self.store.resumed else None
        if rec is None:
            return False
        self.rows += rec["rows"]
        self.values.update(rec["values"])
        self.grids += rec["grids"]
        self.figure5, self.figure8, self.speed = rec["figure5"], rec["figure8"], rec["speed"]
        self.say(f"{rec['label']}: {len(rec['rows'])} rows (checkpoint)")
        return True

    def checkpoint(self, index: int, label: str, mark: tuple[int, int, int]) -> None:
        """Save what material ``index`` added since ``mark`` (rows, values, grids)."""
        rows, values, grids = mark
        record = {"label": label, "rows": self.rows[rows:],
                  "values": dict(list(self.values.items())[values:]),
                  "grids": self.grids[grids:], "figure5": self.figure5,
                  "figure8": self.figure8, "speed": self.speed}  # fmt: skip
        self.store.save_material(index, record, self.timings, self.elapsed())

    def mark(self) -> tuple[int, int, int]:
        return len(self.rows), len(self.values), len(self.grids)

    # -- the run ------------------------------------------------------------------------------
    def run(self, out: str | os.PathLike[str], extra: Sequence[str],
            previous: str | os.PathLike[str] | None,
            resume: bool = False) -> dict[str, Any]:  # fmt: skip
        from .report import previous_record, write_report
        from .resume import PARTIAL, Progress

        cfg = self.cfg
        prev = None if previous is None else previous_record(previous)  # fail before the hour
        self.out = out = Path(out)
        self.store = Progress(out / PARTIAL, resume, cfg, self.seed, extra, self.methods)
        self.t_start = time.perf_counter()
        if self.store.resumed and (last := self.store.latest()) is not None:
            self.timings = dict(last["timings"])  # the pieces' times add up
            self.t_start -= last["seconds"]
            self.say(f"resuming from {self.store.folder} (resumed {self.store.resumed} times)")
        t0 = time.perf_counter()
        train, tests, table5 = self.materials(extra)
        self.stage("materials", t0)
        self.fit(train)

        order = itertools.count()
        ahead = self.code_ahead([(i, *t) for i, t in enumerate(tests)], "test", cfg.levels)
        for label, cls, mseed, btf in tests:
            if self.done(k := next(order)):
                continue
            mark = self.mark()
            pending, recs, views = self.code_set("test", label, cls, mseed, btf, cfg.levels,
                                                 ahead.pop(k, None))  # fmt: skip
            self.say(f"{label}: metrics of {sum(v is not None for _, v in pending)} "
                     "reconstructions")
            self.score(btf, pending)
            if recs and len(self.grids) - len(self.figure5) < 2:
                self.grid(btf, recs, f"grid_{label}.png")
            if not self.figure5 and (name := self.figure5_grid(label, btf, views)):
                self.figure5 = [name]
            if not self.speed and not self.figure8:
                self.renders_and_speed(label, btf, views)
            self.checkpoint(k, label, mark)

        t5_levels = tuple(cfg.table5_levels) or tuple(cfg.levels)
        ahead = self.code_ahead([(len(tests) + i, *t) for i, t in enumerate(table5)], "table5",
                                t5_levels)  # fmt: skip
        for label, cls, mseed, btf in table5:
            if self.done(k := next(order)):
                continue
            mark = self.mark()
            pending, recs, _ = self.code_set("table5", label, cls, mseed, btf, t5_levels,
                                             ahead.pop(k, None))  # fmt: skip
            self.say(f"{label}: metrics of {sum(v is not None for _, v in pending)} "
                     "reconstructions")
            self.score(btf, pending)
            if recs:
                self.grid(btf, recs, f"grid_{label}_table5.png")
            self.checkpoint(k, label, mark)

        for cls, mseed in cfg.black_materials:
            if not self.done(k := next(order)):
                mark = self.mark()
                self.black(cls, mseed)
                self.checkpoint(k, f"{_label(cls, mseed)}+black", mark)

        result = self.result(extra, self.figure5)
        result["resumed"] = self.store.resumed
        if prev is not None:
            result["previous"] = prev
        t0 = time.perf_counter()
        write_report(result, out)
        self.stage("report", t0)
        result["timings_seconds"] = self.timings
        with atomic_output(out / "results.json") as tmp:
            tmp.write_text(json.dumps(result, indent=2, default=json_default))
        self.store.finish()
        self.say(f"wrote {out / 'results.json'} and {out / 'results.md'} "
                 f"({result['seconds']:.0f} s)")
        return result

    def result(self, extra: Sequence[str], figure5: list[str]) -> dict[str, Any]:
        cfg = self.cfg
        models = {}
        for m in self.methods:
            rec = getattr(m, "model_record", None)
            if callable(rec) and (entry := rec()) is not None:
                models[m.name] = entry
        runs = {
            m.name: {
                "label": m.label, "scope": m.scope, "matchings": list(m.matchings),
                "sets": list(m.sets), "factors": list(m.factors),
                "class": f"{type(m).__module__}:{type(m).__qualname__}",
                "reference": m is self.ref, "shared_bytes": int(m.shared_bytes()),
                "training_budget": m.training_budget(), "params": m.describe(),
            }
            for m in self.methods
        }  # fmt: skip
        return {
            "benchmark": "sparsebtf bench quality",
            "config": asdict(cfg),
            "seed": self.seed,
            "extra_materials": list(extra),
            "level_ratios_per_material": {str(k): v for k, v in cfg.ratios().items()},
            "models": models,
            "methods": {**{m.name: m.label for m in self.methods}, **VARIANTS,
                        **{k + suffix: f"{v} [{suffix[1:]}]" for _, suffix in self.coders[1:]
                           for k, v in VARIANTS.items()}},
            "method_runs": runs,
            "rows": self.rows,
            "material_values": self.values,
            "grids": self.grids,
            "figure5": figure5,
            "figure8": self.figure8,
            "decode_speed": self.speed,
            "timings_seconds": self.timings,
            "seconds": self.elapsed(),
            "machine": {
                "cpus": os.cpu_count(),
                "platform": platform.platform(),
                "python": platform.python_version(),
                "numpy": np.__version__,
                "library": library_version(),
            },
            "created": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        }

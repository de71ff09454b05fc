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
"""

from __future__ import annotations

import copy
import itertools
import json
import os
import platform
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from .._atomic import atomic_output
from .._json import json_default
from .._version import library_version
from ..data.btf import BTF
from ..errors import BTFInputError
from ..execution import Executor, executor
from ..figures import comparison_grid
from ..points.statistics import positive_median
from .benchmark_set import FLOOR, BenchConfig, reference_level
from .methods import PAPER, Budget, Coding, FitContext, Method
from .methods.selection import resolve_methods
from .scoring import score_many

__all__ = ["METHODS", "VARIANTS", "run_quality"]

#: the reference's true-black variants (rows of set "black"), by row method
VARIANTS = {
    "release": "SparseBTF, release log offset 1e-5",
    "floored": "SparseBTF on the copy floored at 1e-3",
}
#: Method labels of the default non-neural methods and the true-black variants.
METHODS = {
    "sparsebtf": "SparseBTF",
    "rate": "SparseBTF + rate control",
    "per_channel": "SparseBTF, per-channel std",
    "raw": "[MHU19] (raw RGB)",
    "pca_log": "PCA (log)",
    "pca_linear": "PCA (linear)",
    **VARIANTS,
}
#: the methods of the Figure 5 image (reference, SparseBTF(32) and these at 32) when present
FIGURE5 = ("rgjw20",)
#: the metrics of every row (``mse_display`` is None where the scoring does not give it)
METRICS = ("mse_rgb", "mse_display", "mse_log", "mse_std", "psnr_rgb", "ssim", "reference_max",
           "max_decoded", "top_error_share")  # fmt: skip


def _figure_pairs(btf: BTF) -> list[tuple[int, int]]:
    """The paper's Figure 4/5 configurations snapped to the nearest sampled directions."""

    def d(theta: float, phi: float) -> np.ndarray:
        t, p = np.radians(theta), np.radians(phi)
        return np.array([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)])

    wanted = [((23.5, 270.0), (11.0, 15.0)), ((45.0, 0.0), (60.0, 15.0))]
    return [
        (int(btf.lights.nearest(d(*lt))[0][0]), int(btf.views.nearest(d(*vw))[0][0]))
        for lt, vw in wanted
    ]


def _metrics(ref: BTF, recs: Sequence[BTF], cfg: BenchConfig) -> list[dict[str, Any]]:
    """Every metric of every reconstruction of ``ref``, in one pass over it."""
    scores = score_many(
        ref, recs, ssim_images=cfg.ssim_images, tile=2 * cfg.patch, progress=False
    )
    return [{k: (float(m[k]) if m.get(k) is not None else None) for k in METRICS}
            for m in scores]  # fmt: skip


class _Log:
    def __init__(self, fn: Callable[[str], None]) -> None:
        self.fn = fn
        self.t0 = time.perf_counter()

    def __call__(self, msg: str) -> None:
        self.fn(f"[{time.perf_counter() - self.t0:7.1f} s] {msg}")


def floored(btf: BTF, floor: float) -> BTF:
    """``btf`` with every value raised to at least ``floor`` (lazy, view block by view block)."""
    from ..data.btf import FunctionBTF

    def block(v: int) -> np.ndarray:
        return np.maximum(btf.view_block(v), np.float32(floor))

    return FunctionBTF((btf.height, btf.width), btf.lights, btf.views, block,
                       name=f"{btf.name}-floor{floor:g}")  # fmt: skip


def _label(cls: str, seed: int) -> str:
    return f"{cls}{seed:02d}"


def _view_at(views: dict[tuple[int, str], BTF], level: int) -> BTF | None:
    """A method's reconstruction at ``level`` from its views by (level, matching): the
    reference's (matching ""), else the paper's matching where the method was coded under it,
    else any other; None when it has none at that level."""
    for key in ((level, ""), (level, PAPER)):
        if key in views:
            return views[key]
    return next((v for (lv, _), v in views.items() if lv == level), None)


def budgets_for(
    method: Method, btf: BTF, levels: Sequence[int], reference_bytes: dict[int, int]
) -> list[Budget]:
    """The budgets ``method`` codes ``btf`` at: per matching it declares, per level, per
    factor: ``per_material`` = factor × the reference's per-material bytes on ``btf``,
    ``paper`` = factor × 2·L·H·W (L binary16 values per texel)."""
    texels = btf.height * btf.width
    out = []
    for matching in method.matchings:
        for lv in levels:
            base = 2 * lv * texels if matching == PAPER else reference_bytes[lv]
            out += [Budget(lv, int(f * base), matching, f) for f in method.factors]
    return out


def method_row(base: dict[str, Any], method: str, level: int | None, budget: Budget | None,
               coding: Coding) -> dict[str, Any]:  # fmt: skip
    """A result row without its metrics: the material, the method, the budget it was coded
    at (none for the reference), the coding's own fields and bytes."""
    row = {**base, "method": method, "level": level}
    if budget is not None:
        row.update(matching=budget.matching, budget_factor=budget.factor,
                   budget_bytes=budget.material_bytes)  # fmt: skip
    row.update(coding.info)
    row["material_bytes"] = int(coding.material_bytes)
    if coding.note:
        row["note"] = coding.note
    return row


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


@dataclass
class _Coded:
    """One material's codings under way: its rows so far (the reference's), grid
    reconstructions, views, the reference's bytes per level, and the other methods' tasks."""

    base: dict[str, Any]
    which: str
    pending: list[tuple[dict[str, Any], BTF | None]] = field(default_factory=list)
    recs: dict[str, BTF] = field(default_factory=dict)
    views: dict[str, dict[tuple[int, str], BTF]] = field(default_factory=dict)
    ref_bytes: dict[int, int] = field(default_factory=dict)
    tasks: dict[str, Any] = field(default_factory=dict)


def _code_task(method: Method, btf: BTF, budgets: Sequence[Budget]) -> tuple[list, list]:
    """A cluster task: ``method.code(btf, budgets)`` with the worker's copy of the method,
    and what the coding added to that copy's accounting (:meth:`~.methods.Method.cost_log`,
    replayed on the run's method). The worker's shared copy is copied again: tasks on one
    worker share it across threads, and ``code`` adds to the accounting it holds."""
    method = copy.deepcopy(method)
    before = len(method.cost_log())
    codings = method.code(btf, budgets)
    return codings, list(method.cost_log()[before:])


class _QualityRun:
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

    # -- 1. materials -----------------------------------------------------------------------
    def materials(self, extra: Sequence[str]) -> tuple[list[BTF], list, list]:
        from ..open import open_btf

        cfg = self.cfg
        self.say(f"materials: {cfg.n_train} training, {len(cfg.test_set())} test, "
                 f"{len(cfg.table5_materials)} Table-5 ({cfg.directions} directions, "
                 f"{cfg.source}; cached)")  # fmt: skip
        train = [cfg.material(c, cfg.train_size, s) for c, s in cfg.train_set()]
        tests: list[tuple[str, str, int | None, BTF]] = [
            (_label(c, s), c, s, cfg.material(c, cfg.test_size, s)) for c, s in cfg.test_set()
        ]
        for src in extra:
            b = open_btf(src)
            if not (b.lights.equals(train[0].lights) and b.views.equals(train[0].views)):
                raise BTFInputError(
                    f"--materials {src}: {len(b.lights)} x {len(b.views)} directions, but the "
                    f"benchmark uses {cfg.directions} ({len(train[0].lights)} x "
                    f"{len(train[0].views)})"
                )
            if b.height % cfg.patch or b.width % cfg.patch:
                raise BTFInputError(
                    f"--materials {src}: {b.height}x{b.width} texels is not a multiple of the "
                    f"patch {cfg.patch}; crop it first (sparsebtf convert --crop)"
                )
            tests.append((Path(str(b.name)).stem or src, "extra", None, b))
        table5 = [(_label(c, s), c, s, cfg.material(c, cfg.table5_size, s))
                  for c, s in cfg.table5_materials]  # fmt: skip
        return train, tests, table5

    # -- 2. fitting -------------------------------------------------------------------------
    def fit(self, train: list[BTF]) -> None:
        cfg = self.cfg
        ctx = FitContext(levels=tuple(cfg.levels), level_bytes_per_texel={}, patch=cfg.patch,
                         seed=self.seed, progress=self.progress, executor=self.ex, config=cfg,
                         out=self.out)
        saved = self.store.methods() if self.store.resumed else None
        if saved is not None:
            self.adopt(saved["methods"])
            for m in self.methods:  # a checkpoint's contexts lost their executor: this run's
                if isinstance(getattr(m, "context_", None), FitContext):
                    m.context_ = replace(m.context_, executor=self.ex)  # type: ignore[attr-defined]
        for i, m in enumerate(self.methods):
            t0 = time.perf_counter()
            if saved is not None and i < saved["fitted"]:
                self.say(f"{m.label}: fitted (checkpoint)")
            else:
                if m.scope == "shared":  # a per-material method is fitted on each material
                    self.say(f"fitting {m.label} on {len(train)} training materials")
                m.fit(train, ctx)
                self.stage(f"train_{m.name}", t0)
                self.store.save_methods(self.methods, i + 1, self.timings, self.elapsed())
            if m is self.ref:
                per_texel = 3 * len(train[0].lights) * len(train[0].views)
                ctx = replace(ctx, reference=m,
                              level_bytes_per_texel=m.level_bytes_per_texel(cfg.levels,
                                                                            per_texel))
        self.ctx = ctx

    # -- 3./4. coding and scoring ------------------------------------------------------------
    def note_values(self, label: str, btf: BTF) -> None:
        # each scored material's median positive value and share of values <= 0 (the sample
        # of the auto log offset): with the rows' largest value, its dynamic range
        median, zeros = positive_median(btf)
        self.values[label] = {"median": median, "nonpositive_share": zeros}

    def score(self, btf: BTF, pending: list[tuple[dict[str, Any], BTF | None]]) -> None:
        """Metrics of every pending reconstruction of ``btf`` in one pass, then the rows in
        order (a row without a reconstruction gets None metrics)."""
        t0 = time.perf_counter()
        recs = [v for _, v in pending if v is not None]
        mets = iter(_metrics(btf, recs, self.cfg) if recs else [])
        empty = dict.fromkeys(METRICS)
        for row, view in pending:
            self.rows.append({**row, **(next(mets) if view is not None else empty)})
        self.stage("evaluate", t0)

    def code_set(self, which: str, label: str, cls: str, mseed: int | None, btf: BTF,
                 levels: Sequence[int], ahead: _Coded | None = None,
                 ) -> tuple[list, dict[str, BTF], dict]:  # fmt: skip
        """The reference and every method coding set ``which``, on one material: pending
        rows, grid reconstructions, and per method name its views by (level, matching).
        ``ahead``: the material's :meth:`code_reference`, its other methods already submitted
        (a cluster run codes the next materials' while this one's finish)."""
        coded = ahead or self.code_reference(which, label, cls, mseed, btf, levels)
        return self.code_others(coded, btf, levels)

    def code_reference(self, which: str, label: str, cls: str, mseed: int | None, btf: BTF,
                       levels: Sequence[int], submit: bool = False) -> _Coded:  # fmt: skip
        """The reference's codings of one material (and with ``submit``, on a cluster, the
        other methods' as tasks: their per-material budgets follow the reference's bytes)."""
        cfg = self.cfg
        base = {"material": label, "class": cls, "seed": mseed, "set": which,
                "size": [btf.height, btf.width]}
        self.note_values(label, btf)
        coded = _Coded(base, which)
        budgets = self.ref.level_budgets(btf, levels)
        curve = which == "test"
        self.say(f"{label}: {self.ref.label} at levels {list(levels)} (tau "
                 f"{[list(self.ref.level_tau(btf, lv)) for lv in levels]})"
                 + (f" and {len(self.ref.curve_taus)} curve points" if curve else ""))
        t0 = time.perf_counter()
        codings = self.ref.code(btf, budgets, curve=curve)
        self.stage(f"encode_{self.ref.name}", t0)
        for j, c in enumerate(codings):
            lv = budgets[j].level if j < len(budgets) else None
            coded.pending.append((method_row(base, self.ref.name, lv, None, c),
                                  c.reconstruction))  # fmt: skip
            if lv is not None:
                coded.ref_bytes[lv] = c.material_bytes
                coded.views.setdefault(self.ref.name, {})[(lv, "")] = c.reconstruction
                if lv in cfg.grid_levels:
                    coded.recs[f"{self.ref.label}({lv})"] = c.reconstruction
        if submit:
            data = self.ex.constant(btf)
            for m in self.others:
                if which in m.sets:
                    bs = budgets_for(m, btf, levels, coded.ref_bytes)
                    coded.tasks[m.name] = self.ex.submit(_code_task, self._remote(m), data, bs)
        return coded

    def _remote(self, m: Method) -> Any:
        """The method as the cluster's tasks share it (sent once per run)."""
        if m.name not in self._remote_methods:
            self._remote_methods[m.name] = self.ex.constant(m)
        return self._remote_methods[m.name]

    def code_others(self, coded: _Coded, btf: BTF,
                    levels: Sequence[int]) -> tuple[list, dict[str, BTF], dict]:  # fmt: skip
        cfg = self.cfg
        label, which = coded.base["material"], coded.which
        pending, recs, views = coded.pending, coded.recs, coded.views
        for m in self.others:
            if which not in m.sets:
                continue
            bs = budgets_for(m, btf, levels, coded.ref_bytes)
            self.say(f"{label}: {m.label} at {len(bs)} budgets "
                     f"({', '.join(m.matchings)}; bytes {[b.material_bytes for b in bs]})")
            t0 = time.perf_counter()
            task = coded.tasks.pop(m.name, None)
            if task is None:
                cs = m.code(btf, bs)
            else:
                cs, log = self.ex.gather([task])[0]
                m.replay(log)
            self.stage(f"encode_{m.name}", t0)
            if len(cs) != len(bs):
                raise BTFInputError(f"method {m.name!r}: code() returned {len(cs)} codings "
                                    f"for {len(bs)} budgets (one per budget, in order)")
            top = max(m.factors)
            for b, c in zip(bs, cs, strict=True):
                pending.append((method_row(coded.base, m.name, b.level, b, c),
                                c.reconstruction))  # fmt: skip
                if c.reconstruction is None or b.factor != top:
                    continue
                views.setdefault(m.name, {})[(b.level, b.matching)] = c.reconstruction  # type: ignore
                if m.grid and b.matching == m.matchings[0] and b.level in cfg.grid_levels:
                    f = "" if b.factor == 1 else f" {b.factor:g}x"
                    recs[f"{m.label}{f}({b.level})"] = c.reconstruction
        return pending, recs, views

    def code_ahead(self, items: list[tuple[int, str, str, int | None, BTF]], which: str,
                   levels: Sequence[int]) -> dict[int, _Coded]:  # fmt: skip
        """On a cluster: every not-yet-checkpointed material's reference coding, with the other
        methods' codings submitted as tasks, by run index; {} in process (each material is
        coded when its turn comes)."""
        if not self.ex.distributed or not self.others:
            return {}
        ahead = {}
        for k, label, cls, mseed, btf in items:
            if not (self.store.resumed and self.store.material(k) is not None):
                ahead[k] = self.code_reference(which, label, cls, mseed, btf, levels, True)
        return ahead

    def grid(self, btf: BTF, recs: dict[str, BTF], name: str) -> None:
        t0 = time.perf_counter()
        path = comparison_grid(btf, recs, _figure_pairs(btf), self.out / name)
        self.grids.append(path.name)
        self.stage("figures", t0)

    def figure5_grid(self, label: str, btf: BTF, views: dict) -> str | None:
        """Figure 5's image: the reference, SparseBTF(32) and RGJW20(32) (the paper's
        matching where coded under it), when RGJW20 is in the run."""
        lv = reference_level(self.cfg.levels)
        recs = {f"{self.ref.label}({lv})": views[self.ref.name][(lv, "")]}
        for m in self.others:
            if m.name in FIGURE5 and m.name in views:
                v = _view_at(views[m.name], lv)
                if v is not None:
                    recs[f"{m.label}({lv})"] = v
        if len(recs) < 2:
            return None
        self.grid(btf, recs, f"figure5_{label}.png")
        return self.grids[-1]

    def renders_and_speed(self, label: str, btf: BTF, views: dict) -> None:
        """Figure 8 (each method's reconstruction at the reference level rendered beside the
        reference, :func:`~.renders.render_methods`) and Table 1's single-value decode speed
        (:func:`~.speed.decode_speed`), on the first test material."""
        cfg = self.cfg
        lv = reference_level(cfg.levels)
        recs: dict[str, BTF] = {}
        for m in self.methods:
            v = _view_at(views.get(m.name, {}), lv)
            if v is not None:
                recs[f"{m.label}({lv})"] = v
        if cfg.speed_seconds > 0:
            from .speed import decode_speed

            t0 = time.perf_counter()
            self.say(f"{label}: single-value decode speed of {len(recs)} methods")
            self.speed = {"material": label, "level": lv, "methods": decode_speed(
                recs, batch=cfg.speed_batch, seconds=cfg.speed_seconds, seed=self.seed)}
            self.stage("decode_speed", t0)
        if cfg.render_spp > 0:
            from .renders import render_methods

            t0 = time.perf_counter()
            self.say(f"{label}: Figure 8, {len(recs)} methods rendered at {cfg.render_spp} spp")
            res = render_methods(btf, recs, self.out / "figure8", spp=cfg.render_spp,
                                 image_size=cfg.render_size, seed=self.seed,
                                 progress=self.progress)
            self.figure8 = {"material": label, "level": lv, "spp": cfg.render_spp,
                            "image_size": cfg.render_size, "methods": res}
            self.stage("figure8", t0)

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

    # -- 5. true black ------------------------------------------------------------------------
    def black(self, cls: str, mseed: int) -> None:
        """A true-black material coded by the reference three ways (configured log offset,
        the release's 1e-5, a copy floored at 1e-3), scored against the unfloored one."""
        cfg = self.cfg
        btf = cfg.material(cls, cfg.test_size, mseed, black=True)
        label = f"{_label(cls, mseed)}+black"
        base = {"material": label, "class": cls, "seed": mseed, "set": "black",
                "size": [btf.height, btf.width]}
        self.note_values(label, btf)
        budgets = self.ref.level_budgets(btf, cfg.levels)
        variants = [(self.ref.name, btf, cfg.log_offset),
                    ("floored", floored(btf, FLOOR), "release")]  # fmt: skip
        if cfg.log_offset != "release":
            variants.insert(1, ("release", btf, "release"))
        pending: list[tuple[dict[str, Any], BTF | None]] = []
        for (coder, suffix), (method, src, rule) in itertools.product(self.coders, variants):
            self.say(f"{label}: {METHODS.get(method, self.ref.label)}{suffix} at tau "
                     f"{[list(self.ref.level_tau(btf, lv)) for lv in cfg.levels]} (log offset "
                     f"{rule})")  # fmt: skip
            t0 = time.perf_counter()
            cs = coder.code(src, budgets, log_offset=rule)
            self.stage("encode_black", t0)
            for b, c in zip(budgets, cs, strict=True):
                pending.append((method_row(base, method + suffix, b.level, None, c),
                                c.reconstruction))  # fmt: skip
        self.say(f"{label}: metrics of {len(pending)} reconstructions (against the unfloored "
                 "BTF)")
        self.score(btf, pending)

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

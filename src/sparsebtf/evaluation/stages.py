"""The quality benchmark's stages: its materials, fitting the methods, coding every
material with every method at its budgets, scoring the reconstructions, and the true-black
materials (the steps of :mod:`.runner`'s pipeline but its figures, :mod:`.figure_stages`;
the run calls them in turn).
"""

from __future__ import annotations

import copy
import itertools
import time
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from ..data.btf import BTF
from ..errors import BTFInputError
from ..points.statistics import positive_median
from .benchmark_set import FLOOR, BenchConfig
from .methods import PAPER, Budget, Coding, FitContext, Method
from .scoring import score_many

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
#: the metrics of every row (``mse_display`` is None where the scoring does not give it)
METRICS = ("mse_rgb", "mse_display", "mse_log", "mse_std", "psnr_rgb", "ssim", "reference_max",
           "max_decoded", "top_error_share")  # fmt: skip


def _metrics(ref: BTF, recs: Sequence[BTF], cfg: BenchConfig) -> list[dict[str, Any]]:
    """Every metric of every reconstruction of ``ref``, in one pass over it."""
    scores = score_many(
        ref, recs, ssim_images=cfg.ssim_images, tile=2 * cfg.patch, progress=False
    )
    return [{k: (float(m[k]) if m.get(k) is not None else None) for k in METRICS}
            for m in scores]  # fmt: skip


def floored(btf: BTF, floor: float) -> BTF:
    """``btf`` with every value raised to at least ``floor`` (lazy, view block by view block)."""
    from ..data.btf import FunctionBTF

    def block(v: int) -> np.ndarray:
        return np.maximum(btf.view_block(v), np.float32(floor))

    return FunctionBTF((btf.height, btf.width), btf.lights, btf.views, block,
                       name=f"{btf.name}-floor{floor:g}")  # fmt: skip


def _label(cls: str, seed: int) -> str:
    return f"{cls}{seed:02d}"


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


class _Stages:
    """The stages of :class:`~.runner._QualityRun`, which holds their state (``cfg``,
    ``seed``, ``say``, ``progress``, ``ex``, the methods, ``rows``, ``values``, ``store``,
    ``out``) and times them (``stage``, ``elapsed``)."""

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

"""``sparsebtf bench quality``: the paper's comparative evaluation on our benchmark.

Pipeline (every number lands in ``results.json``; :mod:`.report` turns it into tables, plots
and ``results.md``):

1. materials of :class:`~.benchmark_set.BenchConfig` (synthetic, cached) plus ``--materials``;
2. three models trained on the same training points:
   SparseBTF (log, YUV, the release's shared standardisation), the same with per-channel
   standardisation, and [MHU19] (raw linear RGB: no log, no YUV, no standardisation);
3. every test material coded at the storage levels SparseBTF(16/32/64/128) with a fixed τ per
   point (ε = 0, so every point holds exactly τ coefficients as in the paper's tables), by
   rate control at exactly the fixed-τ bytes, and with the two other models at equal bytes;
   plus the extra τ_t of the Figure 3 curves;
4. the Table 5 materials (100 × 100 texels) coded by SparseBTF and by per-material PCA at
   equal and at twice SparseBTF's bytes, in the log and in the linear domain;
5. true-black materials (exact zeros, high dynamic range; ``BenchConfig.black_materials``)
   coded at every level with the configured log offset, with the release's 1e-5, and as a
   copy floored at 1e-3, all scored against the unfloored material;
6. MSE (linear RGB, the paper's tables), log MSE, PSNR and SSIM for every reconstruction
   (:func:`~.scoring.score_many`: one pass over each material for all its reconstructions,
   each decoded once; the standardised-domain MSE of the coded ones by Parseval from their
   coefficients), the largest decoded value and the worst 0.01 %'s share of the error,
   image grids like Figures 4 and 5.

Bytes are the paper's Table 4 accounting per material: coefficients (2 B value + 3 B
location) + membership and count (1 B each per point and channel) for the sparse methods;
binary16 factors for PCA. The SparseBTF models' shared dictionaries are not in the
per-material bytes (they serve every material); they are reported once per model.
"""

from __future__ import annotations

import json
import os
import platform
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np

from .. import library_version
from .._atomic import atomic_output
from .._json import json_default
from ..codec import encode_levels, encode_rate_levels, train
from ..data.btf import BTF
from ..errors import BTFInputError
from ..execution import Executor, executor
from ..figures import comparison_grid
from ..model import CodedBTF, Model
from ..points.preprocessing import positive_median
from ..runtime import coded_btf_view
from ..storage.accounting import storage_report
from .baselines import (
    allocate_ranks,
    fit_pca_domains,
    pca_bytes,
    pca_rank_for_budget,
    pca_reconstruction,
)
from .benchmark_set import FLOOR, BenchConfig, level_tau
from .scoring import score_many

__all__ = ["METHODS", "run_quality"]

#: Method labels used in rows, tables and plots.
METHODS = {
    "sparsebtf": "SparseBTF",
    "rate": "SparseBTF + rate control",
    "per_channel": "SparseBTF, per-channel std",
    "raw": "[MHU19] (raw RGB)",
    "pca_log": "PCA (log)",
    "pca_linear": "PCA (linear)",
    "release": "SparseBTF, release log offset 1e-5",
    "floored": "SparseBTF on the copy floored at 1e-3",
}


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
    keys = ("mse_rgb", "mse_log", "mse_std", "psnr_rgb", "ssim", "reference_max", "max_decoded",
            "top_error_share")
    scores = score_many(
        ref, recs, ssim_images=cfg.ssim_images, tile=2 * cfg.patch, progress=False
    )
    return [{k: (float(m[k]) if m.get(k) is not None else None) for k in keys} for m in scores]


def _coded_row(coded: CodedBTF, model: Model) -> dict[str, Any]:
    rep = storage_report(coded, model)
    mat = rep["bytes_coefficients"] + rep["bytes_membership_counts"]
    p = coded.n_points
    nnz = rep["nnz"]
    return {
        "material_bytes": int(mat),
        "bytes_raw": int(rep["bytes_raw"]),
        "ratio_per_material": rep["bytes_raw"] / mat,
        # stored bytes of the schema-3 file (None for codes no coded file holds)
        "stored_codes_bytes": rep.get("bytes_stored_codes"),
        "stored_bytes": rep.get("bytes_stored"),
        "ratio_stored": rep.get("compression_ratio_per_material"),
        "bytes_dictionaries_shared": int(rep["bytes_dictionaries"]),
        "nnz": {k: int(v) for k, v in nnz.items()},
        "coefficients_per_point": sum(nnz.values()) / p,
        "n_points": p,
    }


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
) -> dict[str, Any]:
    """Run the benchmark into folder ``out``; returns (and writes) the results object.

    ``materials`` are extra test BTFs (any source :func:`~sparsebtf.open.open_btf`
    accepts: ``.btf``, dense ``.h5``, ``synth:…``); they need the benchmark's directions and
    a size that is a multiple of the patch. ``seed`` shifts every material seed and the
    training seed. ``previous`` (an earlier run's ``results.json``) adds how each verdict
    moved from it. ``client`` / ``scheduler`` / ``workers`` run its training and encoding on a
    Dask cluster (:func:`sparsebtf.execution.executor`; the results do not change).
    """
    with executor(client=client, scheduler=scheduler, workers=workers) as ex:
        return _run_quality(out, config, materials, seed, log, progress, previous, ex)


def _run_quality(
    out: str | os.PathLike[str],
    config: BenchConfig | None,
    materials: Sequence[str],
    seed: int,
    log: Callable[[str], None],
    progress: bool | None,
    previous: str | os.PathLike[str] | None,
    ex: Executor,
) -> dict[str, Any]:
    from ..open import open_btf
    from .report import previous_record, write_report

    cfg = (config or BenchConfig()).with_seed(seed)
    prev = None if previous is None else previous_record(previous)  # fail before the hour
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    say = _Log(log)
    t_start = time.perf_counter()
    timings: dict[str, float] = {}

    def stage(name: str, t0: float) -> None:
        timings[name] = timings.get(name, 0.0) + time.perf_counter() - t0

    # 1. materials -----------------------------------------------------------------------
    t0 = time.perf_counter()
    say(f"materials: {cfg.n_train} training, {len(cfg.test_set())} test, "
        f"{len(cfg.table5_materials)} Table-5 ({cfg.directions} directions, {cfg.source}; cached)")
    train_btfs = [cfg.material(c, cfg.train_size, s) for c, s in cfg.train_set()]
    tests: list[tuple[str, str, int | None, BTF]] = [
        (_label(c, s), c, s, cfg.material(c, cfg.test_size, s))
        for c, s in cfg.test_set()
    ]
    for src in materials:
        b = open_btf(src)
        if not (b.lights.equals(train_btfs[0].lights) and b.views.equals(train_btfs[0].views)):
            raise BTFInputError(
                f"--materials {src}: {len(b.lights)} x {len(b.views)} directions, but the "
                f"benchmark uses {cfg.directions} ({len(train_btfs[0].lights)} x "
                f"{len(train_btfs[0].views)})"
            )
        if b.height % cfg.patch or b.width % cfg.patch:
            raise BTFInputError(
                f"--materials {src}: {b.height}x{b.width} texels is not a multiple of the "
                f"patch {cfg.patch}; crop it first (sparsebtf convert --crop)"
            )
        tests.append((Path(str(b.name)).stem or src, "extra", None, b))
    table5 = [
        (_label(c, s), c, s, cfg.material(c, cfg.table5_size, s))
        for c, s in cfg.table5_materials
    ]
    stage("materials", t0)

    # 2. models ------------------------------------------------------------------------------
    tau_l = tuple(cfg.tau_train)
    raw_tau = max(1, round(sum(tau_l) / 3))
    model_specs = {"sparsebtf": dict(std_mode="shared", tau_train=tau_l)}
    if cfg.with_per_channel:
        model_specs["per_channel"] = dict(std_mode="per_channel", tau_train=tau_l)
    if cfg.with_raw:
        model_specs["raw"] = dict(
            std_mode="shared", tau_train=(raw_tau,) * 3, preprocessing="identity"
        )
    models: dict[str, Model] = {}
    model_info: dict[str, Any] = {}
    for key, spec in model_specs.items():
        t0 = time.perf_counter()
        say(f"training {METHODS[key]}: K={cfg.n_dictionaries}, tau_l={spec['tau_train']}, "
            f"until the objective falls by less than {cfg.tol:g} per iteration (at most "
            f"{cfg.iters}), sample {cfg.sample}")
        models[key] = train(
            train_btfs, n_dictionaries=cfg.n_dictionaries, patch=cfg.patch, sample=cfg.sample,
            max_iter=cfg.iters, tol=cfg.tol, seed=seed, progress=progress, client=ex,
            **spec,  # type: ignore[arg-type]
        )
        stage(f"train_{key}", t0)
        m = models[key]
        model_info[key] = {
            "content_hash": m.content_hash,
            "params": m.params,
            "training": m.training,
            "bytes_dictionaries": int(sum(2 * m.dictionary_entries(ch) for ch in m.channels)),
            "seconds": time.perf_counter() - t0,
        }

    ratios = cfg.ratios()
    rows: list[dict[str, Any]] = []
    # each scored material's median positive value and share of values <= 0 (the sample of
    # the auto log offset): with the rows' largest value, its dynamic range
    values: dict[str, dict[str, Any]] = {}

    def note_values(label: str, btf: BTF) -> None:
        median, zeros = positive_median(btf)
        values[label] = {"median": median, "nonpositive_share": zeros}
    grids: list[str] = []

    def level_budget(btf: BTF, level: int) -> float:
        """Bytes per data point of one material at ``level``."""
        n_pts = (btf.height // cfg.patch) * (btf.width // cfg.patch)
        return 2 * btf.n_values / ratios[level] / n_pts

    def add(base: dict[str, Any], **kw: Any) -> dict[str, Any]:
        row = {**base, **kw}
        rows.append(row)
        return row

    def score(btf: BTF, pending: list[tuple[dict[str, Any], BTF | None]]) -> None:
        """Metrics of every pending reconstruction of ``btf`` in one pass, then the rows in
        order (a row without a reconstruction is added as it is)."""
        t0 = time.perf_counter()
        mets = iter(_metrics(btf, [v for _, v in pending if v is not None], cfg))
        for row, view in pending:
            add(row, **(next(mets) if view is not None else {}))
        stage("evaluate", t0)

    # 3. test materials ---------------------------------------------------------------------
    for label, cls, mseed, btf in tests:
        base = {"material": label, "class": cls, "seed": mseed, "set": "test",
                "size": [btf.height, btf.width]}
        note_values(label, btf)
        recs: dict[str, BTF] = {}
        pending: list[tuple[dict[str, Any], BTF | None]] = []
        lv_taus = [level_tau(level_budget(btf, lv), minimum=tau_l) for lv in cfg.levels]
        say(f"{label}: SparseBTF at levels {list(cfg.levels)} (tau {lv_taus}) and "
            f"{len(cfg.curve_taus)} curve points")
        t0 = time.perf_counter()
        allt = lv_taus + [t for t in cfg.curve_taus if tuple(t) not in lv_taus]
        coded = encode_levels(btf, models["sparsebtf"], allt, eps=0.0,
                              allow_below_training=True, log_offset=cfg.log_offset,
                              candidates=cfg.candidates, progress=progress, client=ex)
        stage("encode_sparsebtf", t0)
        fixed_bytes: dict[int, int] = {}
        for j, (tau, c) in enumerate(zip(allt, coded, strict=True)):
            level = cfg.levels[j] if j < len(cfg.levels) else None
            info = _coded_row(c, models["sparsebtf"])
            view = coded_btf_view(c)
            pending.append(({**base, "method": "sparsebtf", "level": level, "tau": list(tau),
                             **info}, view))
            if level is not None:
                fixed_bytes[level] = info["material_bytes"]
                if level in cfg.grid_levels:
                    recs[f"SparseBTF({level})"] = view
        if cfg.with_rate_control:
            t0 = time.perf_counter()
            targets = [fixed_bytes[lv] for lv in cfg.levels]
            say(f"{label}: rate control at the fixed-tau bytes {targets}")
            rc = encode_rate_levels(btf, models["sparsebtf"], targets, progress=progress,
                                    log_offset=cfg.log_offset, candidates=cfg.candidates,
                                    client=ex)
            stage("encode_rate", t0)
            for lv, c in zip(cfg.levels, rc, strict=True):
                info = _coded_row(c, models["sparsebtf"])
                view = coded_btf_view(c)
                pending.append(({
                    **base, "method": "rate", "level": lv, "tau": list(c.params["tau"].values()),
                    "target_bytes": c.params["rate_control"]["target_material_bytes"], **info,
                }, view))  # fmt: skip
                if lv in cfg.grid_levels:
                    recs[f"+rate control({lv})"] = view
        for key in ("per_channel", "raw"):
            if key not in models:
                continue
            t0 = time.perf_counter()
            if key == "raw":
                taus = [level_tau(level_budget(btf, lv), split=(1.0, 1.0, 1.0),
                                  minimum=(raw_tau,) * 3) for lv in cfg.levels]
            else:
                taus = lv_taus
            say(f"{label}: {METHODS[key]} at tau {taus}")
            cs = encode_levels(btf, models[key], taus, eps=0.0, allow_below_training=True,
                               log_offset=cfg.log_offset, candidates=cfg.candidates,
                               progress=progress, client=ex)
            stage(f"encode_{key}", t0)
            for lv, tau, c in zip(cfg.levels, taus, cs, strict=True):
                view = coded_btf_view(c)
                pending.append(({**base, "method": key, "level": lv, "tau": list(tau),
                                 **_coded_row(c, models[key])}, view))
                if key == "raw" and lv in cfg.grid_levels:
                    recs[f"[MHU19]({lv})"] = view
        say(f"{label}: metrics of {len(pending)} reconstructions")
        score(btf, pending)
        if recs and len(grids) < 2:
            t0 = time.perf_counter()
            path = comparison_grid(btf, recs, _figure_pairs(btf), out / f"grid_{label}.png")
            grids.append(path.name)
            stage("figures", t0)

    # 4. Table 5: SparseBTF vs per-material PCA -------------------------------------------------
    for label, cls, mseed, btf in table5:
        base = {"material": label, "class": cls, "seed": mseed, "set": "table5",
                "size": [btf.height, btf.width]}
        note_values(label, btf)
        t5_levels = tuple(cfg.table5_levels) or tuple(cfg.levels)
        lv_taus = [level_tau(level_budget(btf, lv), minimum=tau_l) for lv in t5_levels]
        say(f"{label} ({btf.height}x{btf.width}): SparseBTF at tau {lv_taus}")
        t0 = time.perf_counter()
        coded = encode_levels(btf, models["sparsebtf"], lv_taus, eps=0.0,
                              allow_below_training=True, log_offset=cfg.log_offset,
                              candidates=cfg.candidates, progress=progress, client=ex)
        stage("encode_sparsebtf", t0)
        recs = {}
        pending = []
        budgets: dict[int, int] = {}
        for lv, tau, c in zip(t5_levels, lv_taus, coded, strict=True):
            info = _coded_row(c, models["sparsebtf"])
            budgets[lv] = info["material_bytes"]
            view = coded_btf_view(c)
            pending.append(({**base, "method": "sparsebtf", "level": lv, "tau": list(tau),
                             **info}, view))
            if lv in cfg.grid_levels:
                recs[f"SparseBTF({lv})"] = view
        n_tex = btf.height * btf.width
        n_ang = len(btf.lights) * len(btf.views)
        max_rank = max(1, pca_rank_for_budget(2 * max(budgets.values()), n_tex, n_ang))
        t0 = time.perf_counter()
        say(f"{label}: PCA ({', '.join(cfg.pca_domains)}) up to total rank {max_rank}")
        domains: Any = tuple(cfg.pca_domains)
        fits = fit_pca_domains(btf, max_rank, domains=domains, power_iters=1, seed=seed,
                               progress=progress)
        stage("pca_fit", t0)
        for domain, fit in zip(cfg.pca_domains, fits, strict=True):
            for lv in t5_levels:
                for factor in (1, 2):
                    budget = factor * budgets[lv]
                    total = pca_rank_for_budget(budget, n_tex, n_ang)
                    ranks = allocate_ranks(fit, total)
                    nbytes = pca_bytes(ranks, n_tex, n_ang)
                    entry = {
                        **base, "method": f"pca_{domain}",
                        "level": lv, "budget_factor": factor, "budget_bytes": int(budget),
                        "ranks": list(ranks), "material_bytes": nbytes,
                        "bytes_raw": 2 * btf.n_values,
                        "ratio_per_material": (2 * btf.n_values / nbytes) if nbytes else None,
                        "bytes_dictionaries_shared": 0,
                    }
                    if sum(ranks) == 0:
                        pending.append(({**entry, "mse_rgb": None, "mse_log": None,
                                         "mse_std": None, "psnr_rgb": None, "ssim": None,
                                         "note": "no component fits in the budget"}, None))
                        continue
                    rec = pca_reconstruction(fit, ranks, btf)
                    pending.append((entry, rec))
                    if lv in cfg.grid_levels and factor == 2 and domain == cfg.pca_domains[0]:
                        recs[f"PCA {domain} 2x({lv})"] = rec
        say(f"{label}: metrics of {sum(v is not None for _, v in pending)} reconstructions")
        score(btf, pending)
        if recs:
            t0 = time.perf_counter()
            path = comparison_grid(btf, recs, _figure_pairs(btf), out / f"grid_{label}_pca.png")
            grids.append(path.name)
            stage("figures", t0)

    # 5. true black: exact zeros and high dynamic range ------------------------------------------
    for cls, mseed in cfg.black_materials:
        btf = cfg.material(cls, cfg.test_size, mseed, black=True)
        label = f"{_label(cls, mseed)}+black"
        base = {"material": label, "class": cls, "seed": mseed, "set": "black",
                "size": [btf.height, btf.width]}
        note_values(label, btf)
        lv_taus = [level_tau(level_budget(btf, lv), minimum=tau_l) for lv in cfg.levels]
        variants = [("sparsebtf", btf, cfg.log_offset), ("floored", floored(btf, FLOOR), "release")]
        if cfg.log_offset != "release":
            variants.insert(1, ("release", btf, "release"))
        pending = []
        for method, src, rule in variants:
            say(f"{label}: {METHODS[method]} at tau {lv_taus} (log offset {rule})")
            t0 = time.perf_counter()
            cs = encode_levels(src, models["sparsebtf"], lv_taus, eps=0.0,
                               allow_below_training=True, log_offset=rule, progress=progress,
                               candidates=cfg.candidates, client=ex)  # fmt: skip
            stage("encode_black", t0)
            for lv, tau, c in zip(cfg.levels, lv_taus, cs, strict=True):
                pending.append(({**base, "method": method, "level": lv, "tau": list(tau),
                                 "log_offset": c.stats.eps, **_coded_row(c, models["sparsebtf"])},
                                coded_btf_view(c)))  # fmt: skip
        say(f"{label}: metrics of {len(pending)} reconstructions (against the unfloored BTF)")
        score(btf, pending)

    result: dict[str, Any] = {
        "benchmark": "sparsebtf bench quality",
        "config": asdict(cfg),
        "seed": seed,
        "extra_materials": list(materials),
        "level_ratios_per_material": {str(k): v for k, v in ratios.items()},
        "models": model_info,
        "methods": METHODS,
        "rows": rows,
        "material_values": values,
        "grids": grids,
        "timings_seconds": timings,
        "seconds": time.perf_counter() - t_start,
        "machine": {
            "cpus": os.cpu_count(),
            "platform": platform.platform(),
            "python": platform.python_version(),
            "numpy": np.__version__,
            "library": library_version(),
        },
        "created": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
    }
    if prev is not None:
        result["previous"] = prev
    t0 = time.perf_counter()
    write_report(result, out)
    stage("report", t0)
    result["timings_seconds"] = timings
    with atomic_output(out / "results.json") as tmp:
        tmp.write_text(json.dumps(result, indent=2, default=json_default))
    say(f"wrote {out / 'results.json'} and {out / 'results.md'} "
        f"({result['seconds']:.0f} s)")
    return result

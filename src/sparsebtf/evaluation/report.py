"""``results.md`` from a ``bench quality`` results object, and ``bench report``.

Everything is computed from ``results.json`` rows — no number is typed by hand — so
``sparsebtf bench report DIR --docs docs`` regenerates ``docs/results.md`` from any run, old
ones included. The parts live in their own modules: the row queries (:mod:`.rows`), the
verdicts (:mod:`.verdicts`, :mod:`.claims3`), the tables (:mod:`.tables`), the plots
(:mod:`.plots`); this module lays them out and writes the files.
"""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path
from typing import Any

from .._atomic import atomic_output
from .._json import json_default
from ..errors import BTFInputError
from .adaptive_verdicts import ADAPTIVE_KEYS, adaptive_figures, adaptive_section
from .captured import captured_section
from .claims3 import CAPACITY_SLACK, NOT_CONVERGED, table3_comparison
from .history import describe, moved, record
from .plots import figure3, learning_curve_rows, learning_curves, quality_storage
from .rows import materials as _materials
from .side_runs import side_runs_section
from .tables import (
    STORAGE_JSON,
    stored_levels,
    stored_section,
    table2,
    table3,
    table5,
    table_black,
    table_storage,
    table_stored,
)
from .tables import markdown_table as _table
from .training_verdicts import TRAINING_KEYS
from .verdicts import objective_lines, summarise

__all__ = [
    "STORAGE_JSON",
    "figure3",
    "objective_line",
    "previous_record",
    "quality_storage",
    "regenerate",
    "render_markdown",
    "rule_line",
    "stored_levels",
    "summarise",
    "table2",
    "table3",
    "table5",
    "table_black",
    "table_storage",
    "table_stored",
    "write_report",
]  # fmt: skip


# -- markdown ---------------------------------------------------------------------------------
def _pct(x: float | None) -> str:
    return "—" if x is None else f"{x:.2f}x"


def _per_level(s: dict[str, Any], key: str = "per_level_geomean") -> str:
    return ", ".join(f"{k}: {_pct(v)}" for k, v in s[key].items())


def _training_line(result: dict[str, Any]) -> str:
    """How the models were trained, from their recorded training (older runs: the config)."""
    cfg = result["config"]
    training = result["models"].get("sparsebtf", {}).get("training", {})
    points = max((t.get("n_points", 0) for t in training.values()), default=0)
    if "tol" not in cfg:
        return (f"{cfg['iters']} iterations on {cfg['sample']:.0%} of the training points "
                f"({points} points per channel)")
    names = result.get("methods", {})
    its = "; ".join(
        f"{names.get(key, key)} " + "/".join(str(t["n_iter"]) for t in m["training"].values())
        for key, m in result["models"].items()
    )
    return (f"{points} training points per channel ({cfg['sample']:.0%} of the training "
            f"materials' points), trained until an iteration lowered the objective by less than "
            f"{cfg['tol']:g} (at most {cfg['iters']}); iterations Y/U/V: {its}")


def rule_line(cfg: dict[str, Any]) -> str:
    """The report's line on the dictionary rule of a run's encodes (runs before the
    screening existed, without ``candidates``, were exhaustive)."""
    if cfg.get("candidates") is None:
        return ("- Dictionary rule of every SparseBTF encode: exhaustive (every point projected "
                "on every dictionary, the paper's rule).")  # fmt: skip
    return (f"- Dictionary rule of every SparseBTF encode: screened (the {cfg['candidates']} "
            "best dictionaries per point by a partial projection coded exactly, the paper's "
            "rule among them; `--exhaustive` runs the paper's).")  # fmt: skip


def objective_line(cfg: dict[str, Any]) -> str:
    """The report's line on the coding objectives of a run's encodes (runs before the option
    existed: log)."""
    objs = list(cfg.get("objectives") or ["log"])
    more = ("; also " + ", ".join(f"{o} (rows sparsebtf-{o}, rate-{o})" for o in objs[1:])
            if len(objs) > 1 else "")  # fmt: skip
    return (f"- Coding objective of every SparseBTF encode: {objs[0]}{more} "
            "(`sparsebtf encode --objective`; [MHU19] on raw RGB always minimises its "
            "linear-RGB error).")


def _objective_flag(cfg: dict[str, Any]) -> str:
    """The ``--objective`` a run was made with, when not the default."""
    objs = list(cfg.get("objectives") or ["log"])
    return "" if objs == ["log"] else f" --objective {','.join(objs)}"


def _methods_flag(result: dict[str, Any]) -> str:
    """The ``--methods`` / ``--method`` a run was made with when it compared a method the
    defaults do not run (one beyond the paper, a user's own); '' otherwise, and for runs
    before methods were recorded. Objective variants come from ``--objective``."""
    from .methods import available_methods
    from .methods.selection import BASELINE_METHODS, NEURAL_METHODS

    runs = {k: v for k, v in (result.get("method_runs") or {}).items()
            if "model_of" not in (v.get("params") or {})}  # fmt: skip
    if set(runs) <= {*BASELINE_METHODS, *NEURAL_METHODS}:
        return ""
    known = [k for k in runs if k in available_methods()]
    own = "".join(f" --method {v['class']}" for k, v in runs.items() if k not in known)
    return f" --methods {','.join(known)}{own}"


def _offset_flag(cfg: dict[str, Any]) -> str:
    """The ``--log-offset`` a run was made with, when not the default."""
    rule = cfg.get("log_offset", "auto")
    return "" if rule == "auto" else f" --log-offset {rule}"


def render_markdown(
    result: dict[str, Any],
    summary: dict[str, Any],
    img: str = "",
    previous: dict[str, Any] | None = None,
    captured: tuple[dict[str, Any], dict[str, Any], str | None] | None = None,
    side_runs: list[str] | None = None,
) -> str:
    """results.md text; ``img`` is the prefix of image links (folder of the PNGs);
    ``previous`` (a :func:`~.history.record`) adds how each verdict moved from that run;
    ``captured`` (a captured run's results, its summary, a link to its results.md) adds its
    verdicts beside these (:func:`~.captured.captured_section`); ``side_runs`` (markdown
    lines, :func:`~.side_runs.side_runs_section`) the verdicts of runs of their own."""
    cfg = result["config"]
    mach = result["machine"]
    lines = [
        "# Quality benchmark: SparseBTF against its baselines",
        "",
        "_Generated by `sparsebtf bench quality` (and `sparsebtf bench report`) from "
        "`results.json`; do not edit by hand._",
        "",
        f"- Command: `sparsebtf bench quality{' --quick' if cfg['name'] == 'quick' else ''}"
        f"{' --seed ' + str(result['seed']) if result['seed'] else ''}"
        f"{' --source capture' if cfg.get('source') == 'capture' else ''}"
        f"{' --test-classes ' + ','.join(cfg['test_classes']) if cfg.get('test_classes') else ''}"
        f"{''.join(' --materials ' + m for m in result.get('extra_materials', []))}"
        f"{_offset_flag(cfg)}"
        f"{_objective_flag(cfg)}"
        f"{_methods_flag(result)}"
        f"{' --exhaustive' if 'candidates' in cfg and cfg['candidates'] is None else ''} "
        "--out DIR`.",
        f"- Run: configuration **{cfg['name']}**, seed {result['seed']}, created "
        f"{result['created']}, {result['seconds'] / 60:.1f} min on {mach['cpus']} CPUs "
        f"({mach['platform']}, Python {mach['python']}, NumPy {mach['numpy']}, sparsebtf "
        f"{mach['library']}).",
        f"- Materials: {_source_text(cfg)}, {cfg['directions']} directions; {cfg['n_train']} "
        "training "
        f"materials of {cfg['train_size']}x{cfg['train_size']} texels (seeds "
        f"{cfg['train_seeds']}), {len(_materials(result, 'test'))} unseen test materials"
        f"{' (classes ' + ', '.join(cfg['test_classes']) + ')' if cfg.get('test_classes') else ''}"
        " of "
        f"{cfg['test_size']}x{cfg['test_size']} (seeds {cfg['test_seeds']}), Table-5 "
        f"materials of {cfg['table5_size']}x{cfg['table5_size']}.",
        f"- Models: K = {cfg['n_dictionaries']} dictionaries per channel, tau_l = "
        f"{tuple(cfg['tau_train'])}, {_training_line(result)}. The paper: K = 8, 18 UBO2014 "
        "materials of 400x400, 10% (2880 points per channel).",
        "- Storage: per-material bytes of the paper's Table 4 (2 B per value + 3 B per "
        "location + 1 B membership + 1 B count per point and channel; PCA: binary16 factors). "
        "Level L keeps the per-material compression ratio of the paper's SparseBTF(L) "
        "(Table 4 with the shared dictionaries removed): "
        + ", ".join(f"{k}: {v:.0f}" for k, v in result["level_ratios_per_material"].items())
        + ". The shared dictionaries are not in any per-material figure; per model they are "
        + ", ".join(f"{k} {v['bytes_dictionaries']:,d} B"
                    for k, v in result["models"].items()) + "." + _shared_parts(result),
        "- Fixed-tau SparseBTF codes every point with exactly tau coefficients (eps = 0), as "
        "in the paper's tables; rate control gets exactly the fixed-tau bytes.",
        "- MSE is on linear RGB over every value (the paper's tables), shown x 1e-4.",
        "- Preprocessing: log offset "
        + (f"'{cfg['log_offset']}' (ln(x + eps), eps per material; release: 1e-5) and the "
           "bound on decoded values kept with the statistics." if "log_offset" in cfg else
           "1e-5 (the release's), no bound (runs before the log offset existed)."),
        rule_line(cfg),
        objective_line(cfg),
    ]
    for n in cfg.get("notes", []):
        lines.append(f"- Note: {n}")
    lines += ["", "## Verdicts", ""]
    if previous:
        lines += [describe(previous, result), "",
                  "| claim | our figure | verdict | moved from the previous run |",
                  "|---|---|---|---|"]
    else:
        lines += ["| claim | our figure | verdict |", "|---|---|---|"]

    def verdict_row(key: str, claim: str, figure: str) -> None:
        cells = [claim, figure, f"**{summary[key]['verdict']}**"]
        if previous:
            cells.append(moved(key, summary, previous) or "—")
        lines.append("| " + " | ".join(cells) + " |")

    if "table2_processing" in summary:
        s = summary["table2_processing"]
        verdict_row("table2_processing", s["claim"],
                    f"MSE ratio {_pct(s['ratio_geomean'])} (geo. mean; per level "
                    f"{_per_level(s)}); better on {s['materials_better']}")
    s = summary["table3_monotone"]
    verdict_row("table3_monotone", s["claim"],
                f"strictly decreasing on {s['materials_monotone']} materials")
    if "table5_pca" in summary:
        s = summary["table5_pca"]
        verdict_row("table5_pca", s["claim"], f"SparseBTF lower on {s['materials_won']}")
    s = summary["table4_check"]
    verdict_row("table4_check", s["claim"], f"{s['ours']:.1f}")
    if "standardisation" in summary:
        s = summary["standardisation"]
        verdict_row("standardisation", f"(release choice) {s['question']}",
                    f"MSE ratio per-channel/shared {_pct(s['ratio_geomean'])}")
    if "true_black" in summary:
        s = summary["true_black"]
        verdict_row("true_black", s["claim"], f"all three hold on {s['materials_ok']}")
    if "rate_control" in summary:
        s = summary["rate_control"]
        dev = s["max_bytes_deviation"]
        verdict_row("rate_control", f"(beyond the paper) {s['question']}",
                    f"gain {_pct(s['gain_geomean'])} (per level "
                    f"{_per_level(s, 'per_level_geomean')}); better on "
                    f"{s['materials_better']}; bytes within {(dev or 0) * 100:.3f}% of target")
    # beyond the paper: training variants (issue 34), adaptive patch sizes (issue 35)
    for key in (*TRAINING_KEYS, *ADAPTIVE_KEYS):
        if key in summary:
            verdict_row(key, summary[key]["claim"], summary[key]["figure"])
    if "table2_metrics" in summary:
        for metric, v in summary["table2_metrics"]["per_metric"].items():
            lines.append(f"| Table 2's processing gain over [MHU19] in {_METRIC_NAMES[metric]} | "
                         f"MSE ratio {_pct(v['ratio_geomean'])}; better on "
                         f"{v['materials_better']} | **{v['verdict']}** |"
                         + (" — |" if previous else ""))
    for key, figure in (("table3_vs_rgjw20", "cells_won"),
                        ("table3_rgjw20_stalls", "rgjw20_gain_geomean"),
                        ("table3_rjgw19_lowest", "cells_lowest")):  # fmt: skip
        if key in summary:
            s = summary[key]
            fig = s.get(figure)
            text = (s.get("why", "—") if fig is None else _pct(fig) if isinstance(fig, float)
                    else str(fig))  # fmt: skip
            if key == "table3_rgjw20_stalls" and fig is not None:
                text = (f"RGJW20 gain 32 → {s['top_level']}: {text}; SparseBTF "
                        f"{_pct(s['sparsebtf_gain_geomean'])}, falls on "
                        f"{s['sparsebtf_falls']} materials")
            elif fig is not None:
                text = f"{text} cells ({s['matching']} matching)"
            if s.get("not_converged") and fig is not None:
                text += f"; {s['not_converged']} cells left out, not converged"
            verdict_row(key, s["claim"], text)
    if "table3_capacity" in summary:
        s = summary["table3_capacity"]
        text = s.get("why", "—") if "pairs_holding" not in s else (
            f"level {s['levels'][1]} <= {CAPACITY_SLACK} x level {s['levels'][0]} on "
            f"{s['pairs_holding']} converged method x material pairs"
            + "".join(f"; fails {f['cell']} ({f['ratio']:.2f}x: {f['cause']})"
                      for f in s["failures"])
            + (f"; {s['not_converged']} pairs not converged" if s["not_converged"] else ""))
        verdict_row("table3_capacity", s["claim"], text)
    lines += ["", "Rules behind the verdicts:", ""]
    for key in ("table2_processing", "table2_metrics", "table3_monotone", "table3_vs_rgjw20",
                "table3_rgjw20_stalls", "table3_rjgw19_lowest", "table3_capacity", "table5_pca",
                "true_black",
                "standardisation", "rate_control", *TRAINING_KEYS, *ADAPTIVE_KEYS):
        if key in summary:
            lines.append(f"- {key}: {summary[key]['rule']}")
    lines += objective_lines(summary)
    lines += adaptive_section(result, summary, img)
    if captured is not None:
        lines += captured_section(result, summary, *captured)
    lines += side_runs or []
    lines += [
        "", "## Table 2 shape: BTF-specific processing vs [MHU19], equal storage",
        "", "MSE x 1e-4, linear RGB. [MHU19] = the same ensemble training and coding on raw "
        "linear R, G, B (no log, no YUV, no standardisation), tau split equally over R, G, B.",
        "", table2(result),
        "", "## Table 3 shape: error vs storage level", "", "MSE x 1e-4.", "", table3(result),
        *_table3_section(result, img),
        "", "## Table 5 shape: SparseBTF vs per-material PCA", "",
        "MSE x 1e-4; r = ranks of R/G/B. PCA (log) factorises ln(RGB + 1e-5) like UBO2014's "
        "own files, PCA (linear) the linear values; the ranks share one budget, allocated by "
        "singular value. The paper compares SparseBTF(32) with PCA at twice the bytes.",
        "", table5(result),
    ]
    if _materials(result, "black"):
        lines += [
            "", "## True black: exact zeros and high dynamic range", "",
            "MSE x 1e-4 against the unfloored material. SparseBTF uses the log offset "
            f"'{cfg.get('log_offset', 'release')}'; the release's 1e-5 and a copy floored at "
            "1e-3 (coded with 1e-5) beside it. Every decoder clamps to the bound kept with the "
            "statistics.", "", table_black(result),
        ]
    lines += [
        "", "## Storage of every method", "", table_storage(result),
        *stored_section(result),
        "", "## Figure 3 shape", "", f"![Figure 3]({img}figure3.png)",
        "", "## Quality vs storage", "", f"![quality vs storage]({img}quality_storage.png)",
        "", "## Image grids (Figures 4 and 5 shape)", "",
        "Reference, reconstructions, and false-colour |error| x2 (normalised by the "
        "reference's peak), at the paper's figure directions.", "",
    ]
    for g in result.get("grids", []):
        lines.append(f"![{g}]({img}{g})")
        lines.append("")
    lines += _figure8_section(result, img)
    lines += _speed_section(result)
    lines += ["## Run time", "", _table(
        ["stage", "seconds"],
        [[k, f"{v:.0f}"] for k, v in sorted(result["timings_seconds"].items())]
        + [["total", f"{result['seconds']:.0f}"]])]
    return "\n".join(lines) + "\n"


def _shared_parts(result: dict[str, Any]) -> str:
    """The other methods' shared parts (a shared decoder), reported apart like the
    dictionaries; '' when none (and for runs before methods were recorded). Rate control codes
    with the reference's model: its dictionaries are the reference's."""
    parts = [f"{v['label']} {v['shared_bytes']:,d} B"
             for k, v in result.get("method_runs", {}).items()
             if v.get("shared_bytes") and k not in result.get("models", {})
             and not v.get("params", {}).get("uses_reference_model")]  # fmt: skip
    return (" Other methods' shared parts, likewise apart: " + ", ".join(parts) + "."
            if parts else "")


_METRIC_NAMES = {"mse_rgb": "linear MSE (the paper's)", "mse_display": "display-mapped MSE",
                 "mse_log": "log MSE"}  # fmt: skip


def _table3_section(result: dict[str, Any], img: str) -> list[str]:
    """results.md's Table 3 comparison (SparseBTF against the neural encodings and any other
    method), one table per storage matching, and the Figure 5 image."""
    lines = ["", "## Table 3: SparseBTF against the neural encodings, equal storage", "",
             "MSE x 1e-4, linear RGB, per unseen test material; one table per storage "
             "matching. RGJW20 is one network for all materials (its decoder shared, reported "
             "apart like SparseBTF's dictionaries), RJGW19 and NeuMIP one per material (their "
             "weights in each material's bytes). The paper's Table 3 (its materials, 100x100): "
             "SparseBTF lower than RGJW20 in 24 of 28 cells; RJGW19 lowest almost "
             "everywhere."]  # fmt: skip
    body = table3_comparison(result)
    if body:
        lines += ["", body]
        if NOT_CONVERGED in body:
            lines += ["", f"{NOT_CONVERGED}: its training reached its effort cap before the "
                      "held-out loss plateaued; the verdicts leave such cells out."]
    else:
        lines += ["", "_No method beyond SparseBTF's own variants in this run (the neural "
                  "ones need PyTorch: `pip install -e \".[neural]\"`)._"]
    lines += _budgets_table(result, img)
    for g in result.get("figure5", []):
        lines += ["", "Figure 5 shape: reference, SparseBTF(32) and RGJW20(32), false-colour "
                  "|error| x2.", "", f"![{g}]({img}{g})"]
    return lines


def _budgets_table(result: dict[str, Any], img: str = "") -> list[str]:
    """Each method's training budget (wall and CPU seconds; training queries seen per texel,
    how many trainings converged and the stop rule where a method reports them) and shared
    bytes; [] for runs before methods were recorded."""
    runs = result.get("method_runs") or {}
    if not runs:
        return []

    def cell(x: Any) -> str:
        if x is None:
            return "—"
        if isinstance(x, dict):  # per channel
            return ", ".join(f"{k} {v}" for k, v in x.items())
        return f"{x:,.0f}" if isinstance(x, float) else str(x)

    def effort(b: dict[str, Any]) -> str:
        lo, hi = b.get("queries_per_texel_min"), b.get("queries_per_texel")
        return cell(hi) if lo is None or lo == hi else f"{cell(float(lo))}–{cell(float(hi))}"

    def rule(b: dict[str, Any]) -> str:
        r = b.get("stop_rule")
        if not isinstance(r, dict):
            return cell(b.get("iterations"))
        return (f"held-out gain < {r['tolerance']:.0%} over the last {r['window']:.0%}; eval "
                f"every {r['eval_every']:,.0f}, from {r.get('min_queries_per_texel') or 0:,.0f}"
                f", cap {r['max_queries_per_texel']:,.0f} queries per texel")

    def converged(b: dict[str, Any]) -> str:
        ft = b.get("finetune_converged")
        return cell(b.get("converged")) + (f" shared, {ft} fine-tunings" if ft else "")

    body = []
    for v in runs.values():
        b = v.get("training_budget") or {}
        body.append([v["label"], v["scope"], f"{v.get('shared_bytes', 0):,d}",
                     cell(b.get("seconds")), cell(b.get("cpu_seconds")), effort(b),
                     converged(b), rule(b)])
    return ["", "Training budgets: seconds of fitting, wall and CPU (a per-material method: over "
            "all the materials it coded), training queries seen per texel (least–most over its "
            "trainings), how many trainings stopped on their held-out plateau rather than at "
            "their cap, the stop rule (iterations per channel for SparseBTF's dictionaries), "
            "and the bytes every material shares.", "",
            _table(["method", "scope", "shared bytes", "seconds", "CPU seconds",
                    "queries per texel", "converged", "stop rule / iterations"], body),
            *_learning_curves_note(result, img)]  # fmt: skip


def _learning_curves_note(result: dict[str, Any], img: str) -> list[str]:
    """The learning-curve figure under the training budgets, when some training recorded its
    held-out loss curve."""
    data = learning_curve_rows(result)
    if not data:
        return []
    mats = sorted({m for d in data.values() for m in d})
    return ["", f"Learning curves: held-out loss (log space, queries outside each texel's "
            f"training pool) against training queries per texel, one line per latent size, on "
            f"{' and '.join(mats)}; a filled end marker stopped on its plateau, a hollow one at "
            "its cap.", "", f"![learning curves]({img}learning_curves.png)"]


def _figure8_section(result: dict[str, Any], img: str) -> list[str]:
    """results.md's Figure 8: renders of each method beside the reference (image MSE, linear
    and display-mapped, and mean HDR-ꟻLIP)."""
    f8 = result.get("figure8") or {}
    if not f8.get("methods"):
        return []
    body = [[label, f"{r['image_mse']:.3g}", f"{r['image_mse_display']:.3g}",
             f"{r['flip']:.4f}"] for label, r in f8["methods"].items()]  # fmt: skip
    # in a run's own folder the image lies in figure8/; regenerate copies it beside the others
    png = f"{img}figure8.png" if img else "figure8/figure8.png"
    return [
        "## Figure 8 shape: renders", "",
        f"{f8['material']} as each method decodes it at level {f8['level']}, decoded on the "
        "measured grid and rendered with the dense Mitsuba plugin (sphere scene, cosine "
        f"sampling, the same paths for every method) at {f8['spp']} spp, "
        f"{f8['image_size']}x{f8['image_size']} pixels. Image MSE of the linear render and "
        "after the paper's display mapping clip(1.3 x^(1/1.8), 0, 1); mean HDR-ꟻLIP "
        "(0 = identical).", "",
        _table(["method", "image MSE", "image MSE, display", "ꟻLIP"], body), "",
        f"![Figure 8]({png})", "",
    ]


def _speed_section(result: dict[str, Any]) -> list[str]:
    """results.md's decode speed (Table 1's "fast local reconstruction")."""
    sp = result.get("decode_speed") or {}
    if not sp.get("methods"):
        return []

    def rate(x: float | None) -> str:
        return "—" if x is None else f"{x:,.0f}"

    body = [[label, r.get("path", ""), str(r.get("backend", "")), rate(r["queries_per_second_1"]),
             rate(r["queries_per_second_batch"]), str(r.get("threads", ""))]
            for label, r in sp["methods"].items()]  # fmt: skip
    batch = next(iter(sp["methods"].values())).get("batch")
    return [
        "## Decode speed: Table 1's fast local reconstruction", "",
        f"Single-value decodes per second on this machine ({sp['material']}, level "
        f"{sp['level']}): one query per call on one thread, and {batch:,d} queries per call. "
        "SparseBTF is the runtime's Eq. 5 lookup; a neural method its decoder in PyTorch.", "",
        _table(["method", "path", "backend", "batch 1 /s", f"batch {batch:,d} /s", "threads"],
               body), "",
    ]


def write_report(result: dict[str, Any], out: str | os.PathLike[str]) -> dict[str, Any]:
    """Write tables (Markdown), figure3.png, quality_storage.png and results.md into ``out``.

    Adds ``summary`` (verdicts) to ``result`` and returns it. A ``previous`` record in
    ``result`` (:func:`~.history.record`) adds how each verdict moved from that run.
    """
    out = Path(out)
    summary = summarise(result)
    result["summary"] = summary
    figure3(result, out / "figure3.png")
    quality_storage(result, out / "quality_storage.png")
    learning_curves(result, out / "learning_curves.png")
    for name, fn in (("table2.md", table2), ("table3.md", table3), ("table5.md", table5)):
        with atomic_output(out / name) as tmp:
            tmp.write_text(fn(result) + "\n")
    with atomic_output(out / "results.md") as tmp:
        tmp.write_text(render_markdown(result, summary, previous=result.get("previous")))
    return summary


def previous_record(path: str | os.PathLike[str]) -> dict[str, Any]:
    """The :func:`~.history.record` of the run whose ``results.json`` is at ``path``."""
    try:
        prev = json.loads(Path(path).read_text())
        return record(prev, prev.get("summary") or summarise(prev))
    except (OSError, ValueError, KeyError, TypeError) as e:
        raise BTFInputError(
            f"--previous {path}: not a readable 'bench quality' results.json ({e})"
        ) from e


def _source_text(cfg: dict[str, Any]) -> str:
    """How results.md names the materials' source (runs before ``source`` existed: synth)."""
    if cfg.get("source") == "capture":
        return (f"captured with Mitsuba 3 (`sparsebtf capture`, {cfg.get('spp')} spp, true "
                f"black, high dynamic range: {', '.join(cfg['classes'])})")  # fmt: skip
    return "synthetic"


def _captured_run(
    result: dict[str, Any], docs: Path, folder: str | os.PathLike[str] | None
) -> tuple[dict[str, Any], dict[str, Any], str | None] | None:
    """(results, summary, link to its results.md) of the captured run for ``result``'s
    results.md, or None (see :func:`regenerate`)."""
    if folder is None:
        if result["config"].get("source") == "capture":
            return None
        folder = docs / "capture" / "results"
        if not (folder / "results.json").exists():
            return None
    path = Path(folder) / "results.json"
    try:
        cap = json.loads(path.read_text())
        if cap["config"].get("source") != "capture":
            raise BTFInputError(f"--captured {folder}: {path} is not a '--source capture' run")
        summary = cap.get("summary") or summarise(cap)
    except (OSError, ValueError, KeyError, TypeError) as e:
        raise BTFInputError(f"--captured {folder}: not a readable 'bench quality' results.json "
                            f"({e})") from e  # fmt: skip
    page = next((p for p in (Path(folder) / "results.md", Path(folder).parent / "results.md")
                 if p.exists()), None)  # fmt: skip
    return cap, summary, None if page is None else os.path.relpath(page, docs)


def regenerate(
    run_dir: str | os.PathLike[str],
    docs: str | os.PathLike[str],
    previous: str | os.PathLike[str] | None = None,
    captured: str | os.PathLike[str] | None = None,
) -> Path:
    """``docs/results.md``, ``docs/results/*.png`` and ``docs/results/results.json`` from a
    finished run's ``results.json``.

    ``captured``: the folder of a ``--source capture`` run (its ``results.json``), whose
    verdicts go beside this run's; by default ``DOCS/capture/results`` when it holds one
    (``sparsebtf bench report CAPTURE_RUN --docs DOCS/capture`` puts it there) and this run is
    not a captured one itself.

    Beside each verdict goes how it moved from a previous run: the ``results.json`` at
    ``previous``; else the run's own ``previous`` record; else the run that ``docs`` held
    until now (``docs/results/results.json``), which this call then replaces. A
    ``benchmarks/bench_storage.py --json`` output named :data:`STORAGE_JSON` in the run's
    folder (else in ``docs/results/``) adds the "stored bytes vs Table 4" section.
    """
    run = Path(run_dir)
    result = json.loads((run / "results.json").read_text())
    summary = summarise(result)
    docs = Path(docs)
    img_dir = docs / "results"
    for folder in (run, img_dir):
        if (folder / STORAGE_JSON).exists():
            result["storage"] = json.loads((folder / STORAGE_JSON).read_text())
            if not (img_dir / STORAGE_JSON).exists() or not (
                    img_dir / STORAGE_JSON).samefile(folder / STORAGE_JSON):  # fmt: skip
                shutil.copyfile(folder / STORAGE_JSON, img_dir / STORAGE_JSON)
            break
    img_dir.mkdir(parents=True, exist_ok=True)
    held = img_dir / "results.json"
    if previous is not None:
        result["previous"] = previous_record(previous)
    elif "previous" not in result and held.exists():
        prev = json.loads(held.read_text())
        if prev.get("created") != result.get("created"):
            result["previous"] = record(prev, prev.get("summary") or summarise(prev))
    result["summary"] = summary
    figure3(result, img_dir / "figure3.png")
    quality_storage(result, img_dir / "quality_storage.png")
    learning_curves(result, img_dir / "learning_curves.png")
    figure8 = ["figure8/figure8.png"] if (result.get("figure8") or {}).get("methods") else []
    for g in [*result.get("grids", []), *figure8, *adaptive_figures(result)]:
        src, dst = run / g, img_dir / Path(g).name
        if src.exists() and not (dst.exists() and src.samefile(dst)):
            shutil.copyfile(src, dst)
    with atomic_output(held) as tmp:  # the storage figures stay in their own file
        kept = {k: v for k, v in result.items() if k != "storage"}
        tmp.write_text(json.dumps(kept, indent=2, default=json_default))
    target = docs / "results.md"
    text = render_markdown(result, summary, img="results/", previous=result.get("previous"),
                           captured=_captured_run(result, docs, captured),
                           side_runs=side_runs_section(docs))
    text = text.replace(
        "from `results.json`;",
        f"from `results.json` (regenerate: `sparsebtf bench report {img_dir} --docs {docs}`);",
    )
    with atomic_output(target) as tmp:
        tmp.write_text(text)
    return target

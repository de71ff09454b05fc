"""The text of ``results.md``: the run's description, the verdict table and the rules
behind it, then the sections in order (the verdicts themselves come from
:func:`~.verdicts.summarise`; :mod:`.report` writes the files).
"""

from __future__ import annotations

from typing import Any

from .adaptive_verdicts import ADAPTIVE_KEYS, adaptive_section
from .captured import captured_section
from .claims3 import CAPACITY_SLACK
from .history import describe, moved
from .rows import materials as _materials
from .sections import _figure8_section, _speed_section, _table3_section
from .tables import markdown_table as _table
from .tables import (
    stored_section,
    table2,
    table3,
    table5,
    table_black,
    table_storage,
)
from .training_verdicts import TRAINING_KEYS
from .verdicts import objective_lines


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


def _source_text(cfg: dict[str, Any]) -> str:
    """How results.md names the materials' source (runs before ``source`` existed: synth)."""
    if cfg.get("source") == "capture":
        return (f"captured with Mitsuba 3 (`sparsebtf capture`, {cfg.get('spp')} spp, true "
                f"black, high dynamic range: {', '.join(cfg['classes'])})")  # fmt: skip
    return "synthetic"

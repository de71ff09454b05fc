"""``results.md``'s section on captured materials: a ``bench quality --source capture`` run's
verdicts beside the synthetic run's, what differs, and whether Table 2's processing gain grows
with the materials' dynamic range.

Everything comes from the two runs' ``results.json`` (no number typed by hand). A material's
dynamic range is its largest value (the rows' ``reference_max``) over its median positive value
(``material_values``, the sample the ``auto`` log offset uses:
:func:`~sparsebtf.points.statistics.positive_median`); runs made before that record existed
have no median, and their materials are left out of the dynamic-range table.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from .history import FIGURES
from .rows import materials

__all__ = ["captured_section", "dynamic_range_rows", "range_trend"]

#: the verdicts compared, in results.md's order
VERDICT_KEYS = ("table2_processing", "table3_monotone", "table5_pca", "true_black",
                "standardisation", "rate_control", "adaptive_patches")  # fmt: skip

#: figure of each verdict: FIGURES' (the "moved from the previous run" column) and true black's
_FIGURE = {**FIGURES, "true_black": ("materials_ok", "{}")}

#: |Spearman ρ| from which the gain is said to follow the dynamic range
TREND_RHO = 0.5


def _test_materials(result: dict[str, Any]) -> list[str]:
    return materials(result, "test")


def dynamic_range_rows(result: dict[str, Any], summary: dict[str, Any]) -> list[dict[str, Any]]:
    """Per test material with a recorded median: largest value, median positive value, their
    ratio, the share of values <= 0, and Table 2's MSE[MHU19] / MSE[SparseBTF] at the reference
    level (:func:`~.verdicts.summarise`'s ``per_material``)."""
    per = summary.get("table2_processing", {}).get("per_material", {})
    values = result.get("material_values", {})
    out = []
    for m in _test_materials(result):
        v = values.get(m)
        tops = [r["reference_max"] for r in result["rows"]
                if r["material"] == m and r.get("reference_max")]  # fmt: skip
        if not v or not v.get("median") or not tops or m not in per:
            continue
        top = max(tops)
        out.append({"material": m, "max": top, "median": v["median"],
                    "range": top / v["median"], "nonpositive_share": v["nonpositive_share"],
                    "table2_ratio": per[m]})  # fmt: skip
    return out


def range_trend(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """Spearman's ρ between the dynamic range and Table 2's ratio over ``rows``, and what it
    says: the gain grows with the dynamic range (ρ >= :data:`TREND_RHO`), falls as it grows
    (ρ <= −:data:`TREND_RHO`), or no clear trend; fewer than 4 materials: too few."""
    n = len(rows)
    if n < 4:
        return {"n": n, "rho": None, "verdict": "too few materials to tell"}
    from scipy.stats import spearmanr

    rho = float(spearmanr([r["range"] for r in rows], [r["table2_ratio"] for r in rows])[0])
    if not np.isfinite(rho):
        verdict = "no clear trend"
    elif rho >= TREND_RHO:
        verdict = "the gain grows with the dynamic range"
    elif rho <= -TREND_RHO:
        verdict = "the gain falls as the dynamic range grows"
    else:
        verdict = "no clear trend"
    return {"n": n, "rho": rho, "verdict": verdict}


def _cell(summary: dict[str, Any], key: str) -> str:
    s = summary.get(key)
    if s is None:
        return "not run"
    field, fmt = _FIGURE.get(key, ("", "{}"))
    fig = s.get(field)
    return (f"{fmt.format(fig)}: " if fig is not None else "") + f"**{s['verdict']}**"


def _claim(key: str, *summaries: dict[str, Any]) -> str:
    for s in summaries:
        if key in s:
            text = s[key].get("claim") or s[key].get("question", key)
            return text if key not in ("standardisation", "rate_control") else (
                f"({'release choice' if key == 'standardisation' else 'beyond the paper'}) "
                + text)
    return key


def _run_line(cap: dict[str, Any]) -> str:
    cfg = cap["config"]
    training = cap.get("models", {}).get("sparsebtf", {}).get("training", {})
    points = max((int(t.get("n_points", 0)) for t in training.values()), default=0)
    return (f"configuration **{cfg['name']}**, created {cap['created']}, "
            f"{cap['seconds'] / 60:.0f} min on {cap['machine']['cpus']} CPUs: "
            f"{', '.join(cfg['classes'])} captured at {cfg.get('spp')} spp, "
            f"{cfg['n_train']} training materials of {cfg['train_size']}x{cfg['train_size']}, "
            f"{len(_test_materials(cap))} test materials of {cfg['test_size']}x"
            f"{cfg['test_size']}, Table-5 materials of {cfg['table5_size']}x"
            f"{cfg['table5_size']}; K = {cfg['n_dictionaries']}, {points} training points per "
            "channel")  # fmt: skip


def captured_section(
    result: dict[str, Any], summary: dict[str, Any], cap: dict[str, Any],
    cap_summary: dict[str, Any], link: str | None = None,
) -> list[str]:  # fmt: skip
    """Markdown lines: the verdicts of the captured run ``cap`` beside this run's, what differs,
    and Table 2's gain against dynamic range; ``link`` points at the captured run's own
    results.md (every table of it)."""
    lines = [
        "", "## On captured materials", "",
        "The same benchmark on BTFs rendered by Mitsuba 3 from geometry (`sparsebtf bench "
        "quality --source capture`; " + _run_line(cap) + ")"
        + (f"; every table in [its own results]({link})" if link else "") + ". Captured "
        "materials have exact zeros (hard shadows with nothing to bounce) and a high dynamic "
        "range; the synthetic ones have neither.", "",
        "| claim | synthetic materials | captured materials | what differs |",
        "|---|---|---|---|",
    ]  # fmt: skip
    for key in VERDICT_KEYS:
        if key not in summary and key not in cap_summary:
            continue
        a, b = summary.get(key), cap_summary.get(key)
        if a is None or b is None:
            differs = "measured on one source only"
        elif a["verdict"] == b["verdict"]:
            differs = "same verdict"
        else:
            differs = "**verdict differs**"
        lines.append(f"| {_claim(key, summary, cap_summary)} | {_cell(summary, key)} | "
                     f"{_cell(cap_summary, key)} | {differs} |")
    ranges = [("captured", r) for r in dynamic_range_rows(cap, cap_summary)]
    ranges += [("synthetic", r) for r in dynamic_range_rows(result, summary)]
    lines += [
        "", "### Table 2's processing gain and dynamic range", "",
        "Per test material: its largest value, its median positive value (the sample of the "
        "auto log offset), their ratio, the share of values <= 0, and MSE[MHU19] / "
        "MSE[SparseBTF] at level " + str(summary.get("reference_level", 32)) + " (above 1: "
        "the log-YUV processing helps).", "",
        "| material | source | largest | median | largest / median | values <= 0 | "
        "MSE ratio [MHU19] / SparseBTF |", "|---|---|---|---|---|---|---|",
    ]  # fmt: skip
    if not ranges:
        lines[-2:] = ["Neither run recorded its materials' medians (runs made before that "
                      "record): no per-material dynamic range."]
    for src, r in sorted(ranges, key=lambda t: t[1]["range"]):
        lines.append(f"| {r['material']} | {src} | {r['max']:.3g} | {r['median']:.3g} | "
                     f"{r['range']:,.0f} | {r['nonpositive_share']:.1%} | "
                     f"{r['table2_ratio']:.2f}x |")  # fmt: skip
    trend = range_trend([r for _, r in ranges])
    rho = "" if trend["rho"] is None else f"Spearman's ρ = {trend['rho']:+.2f} over "
    if ranges:
        lines += ["", f"Does the gain grow with the dynamic range? {rho}{trend['n']} "
                  f"materials: **{trend['verdict']}** (rule: |ρ| >= {TREND_RHO})."]
    if not any(src == "synthetic" for src, _ in ranges):
        tops = [r["reference_max"] for r in result["rows"]
                if r["set"] == "test" and r.get("reference_max")]  # fmt: skip
        if tops:
            lines.append(f"The synthetic run recorded no medians (it predates that record); "
                         f"its test materials' largest values are {min(tops):.3g}–"
                         f"{max(tops):.3g}, and its Table-2 ratio is "
                         f"{_cell(summary, 'table2_processing')}.")  # fmt: skip
    return lines

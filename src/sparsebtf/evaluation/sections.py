"""Sections of ``results.md`` beyond the tables: Table 3 against the neural encodings
(with each method's training budget and the learning curves), Figure 8's renders and
Table 1's decode speed (:mod:`.results_md` puts them in order).
"""

from __future__ import annotations

from typing import Any

from .claims3 import NOT_CONVERGED, table3_comparison
from .plots import learning_curve_rows
from .tables import markdown_table as _table


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


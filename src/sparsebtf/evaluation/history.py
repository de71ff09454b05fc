"""How a benchmark run's verdicts moved from a previous run's (``results.md``'s last column).

A run's key figures — one number per verdict — are kept in a small record (:func:`record`)
that a later run embeds as ``previous`` in its ``results.json``; :func:`moved` writes, per
verdict, the previous figure and verdict beside the new ones, with the models each came from
(training points, iterations), so a reader can tell what changed with the model size.
"""

from __future__ import annotations

from typing import Any

__all__ = ["FIGURES", "describe", "moved", "record"]

#: verdict key → (figure key in its summary entry, how to print it)
FIGURES: dict[str, tuple[str, str]] = {
    "table2_processing": ("ratio_geomean", "{:.2f}x"),
    "table3_monotone": ("materials_monotone", "{}"),
    "table5_pca": ("materials_won", "{}"),
    "standardisation": ("ratio_geomean", "{:.2f}x"),
    "rate_control": ("gain_geomean", "{:.2f}x"),
    "table4_check": ("ours", "{:.1f}"),
    "table3_vs_rgjw20": ("cells_won", "{}"),
    "table3_rgjw20_stalls": ("rgjw20_gain_geomean", "{:.2f}x"),
    "table3_rjgw19_lowest": ("cells_lowest", "{}"),
    "adaptive_patches": ("ratio_geomean", "{:.3f}"),
}


def _models(result: dict[str, Any]) -> dict[str, Any]:
    """Training points and iterations per channel of the SparseBTF model of a run."""
    training = result.get("models", {}).get("sparsebtf", {}).get("training", {})
    return {
        "points": max((int(t.get("n_points", 0)) for t in training.values()), default=0),
        "iterations": {ch: int(t.get("n_iter", 0)) for ch, t in training.items()},
    }


def record(result: dict[str, Any], summary: dict[str, Any]) -> dict[str, Any]:
    """The compact record of a run that a later run keeps as its ``previous``."""
    return {
        "created": result.get("created"),
        "configuration": result.get("config", {}).get("name"),
        "models": _models(result),
        "figures": {
            key: {"figure": summary[key].get(field), "verdict": summary[key].get("verdict")}
            for key, (field, _) in FIGURES.items()
            if key in summary
        },
    }


def describe(previous: dict[str, Any], result: dict[str, Any]) -> str:
    """One sentence naming the previous run and its models (and a different configuration)."""
    m = previous.get("models", {})
    its = sorted(set(m.get("iterations", {}).values()))
    it_text = "/".join(str(i) for i in its) if its else "?"
    text = (f"The last column compares with the previous run ({previous.get('created', '?')}, "
            f"configuration {previous.get('configuration', '?')}: {m.get('points', '?')} "
            f"training points per channel, {it_text} iterations).")
    now = result.get("config", {}).get("name")
    if previous.get("configuration") != now:
        text += f" This run's configuration is {now}: other materials, so compare with care."
    return text


def moved(key: str, summary: dict[str, Any], previous: dict[str, Any] | None) -> str:
    """One verdict's "moved from the previous run" note ('' when there is nothing to compare)."""
    if not previous or key not in FIGURES or key not in summary:
        return ""
    before = previous.get("figures", {}).get(key)
    if before is None:
        return "not in the previous run"
    field, fmt = FIGURES[key]
    now = summary[key].get(field)

    def show(v: Any) -> str:
        return "—" if v is None else fmt.format(v)

    text = f"{show(before['figure'])} → {show(now)}"
    if isinstance(now, float) and isinstance(before["figure"], float) and before["figure"]:
        text += f" ({(now / before['figure'] - 1) * 100:+.0f}%)"
    if before["verdict"] == summary[key].get("verdict"):
        return f"{text}; verdict unchanged"
    return f"{text}; was **{before['verdict']}**"

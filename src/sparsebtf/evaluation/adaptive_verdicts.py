"""The verdict on adaptive patch sizes (issue 35; method :mod:`.methods.adaptive`) and its
section of ``results.md``, every figure from ``results.json``.

The claim (the paper's §5, future work): a rate–distortion quadtree of patch sizes lowers
the error against the reference's fixed P×P patches at equal bytes. The rule
(:func:`adaptive_verdict`): over every test material × level pair, MSE[sparsebtf-adaptive] /
MSE[sparsebtf] (linear RGB, the paper's tables) at the same per-material Table 4 bytes (the
adaptive code's, tree bits included, never above the reference's); the geometric mean of the
pairs below 1 − :data:`MARGIN` is supported, above 1 + :data:`MARGIN` not supported, else no
clear difference; any adaptive code above its budget voids the comparison. Beside it: the
same ratio against rate control (the reference's model with one byte budget over all points
at the fixed size), which separates what the tree's byte allocation gains from what the
smaller patches gain; per material the ratio per level and the share of texels the tree put
in smaller nodes; the encode seconds against a fixed-τ encode of the same levels; a
picture of one material's tree over its texture.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from .rows import get, materials
from .tables import gmean
from .tables import markdown_table as _table

__all__ = ["ADAPTIVE_KEYS", "METHOD", "adaptive_figures", "adaptive_section", "adaptive_verdict",
           "summarise_adaptive"]  # fmt: skip

#: The summary keys of this verdict, in report order.
ADAPTIVE_KEYS = ("adaptive_patches",)
#: The method's rows.
METHOD = "sparsebtf-adaptive"
#: A geometric-mean MSE ratio below 1 − this is a lower error, above 1 + this a higher one.
MARGIN = 0.02


def _word(g: float | None) -> str | None:
    if g is None:
        return None
    return "lower" if g < 1 - MARGIN else "higher" if g > 1 + MARGIN else "same"


def adaptive_verdict(ratios: list[float], bytes_ok: bool,
                     vs_rate: list[float] | None = None) -> str:  # fmt: skip
    """The verdict of the pairs' MSE ratios adaptive / fixed (and adaptive / rate control,
    when measured) by the module's rule."""
    if not bytes_ok:
        return "not measured: an adaptive code went above its budget"
    word = _word(gmean(ratios))
    if word is None:
        return "not measured"
    if word != "lower":
        return "not supported (higher error)" if word == "higher" else "no clear difference"
    rate = _word(gmean(vs_rate or []))
    if rate is None:
        return "supported"
    if rate == "lower":
        return "supported, and lower than rate control too"
    return (f"supported against fixed tau only: {'no lower' if rate == 'same' else 'higher'} "
            "than rate control at the same patch size (the gain is the bytes moved between "
            "points, not the patch sizes)")


def _ratio(result: dict[str, Any], m: str, lv: int, other: str) -> float | None:
    a = get(result, material=m, method=METHOD, level=lv, set="test")
    b = get(result, material=m, method=other, level=lv, set="test")
    if a and b and a.get("mse_rgb") and b.get("mse_rgb"):
        return a["mse_rgb"] / b["mse_rgb"]
    return None


def _std_ratio(result: dict[str, Any], m: str, lv: int, key: str) -> float | None:
    """The coder's error (standardised, from the codes) of ``key`` over the fixed code's."""
    a = get(result, material=m, method=METHOD, level=lv, set="test") or {}
    return a[key] / a["mse_std_fixed"] if a.get(key) and a.get("mse_std_fixed") else None


def _fig(x: float | None, fmt: str = "{:.3f}") -> str:
    return "—" if x is None else fmt.format(x)


def summarise_adaptive(result: dict[str, Any], levels: list[int], mid: int) -> dict[str, Any]:
    """``{"adaptive_patches": ...}`` when the run has the method's rows, else ``{}``."""
    rows = [r for r in result["rows"] if r["method"] == METHOD and r["set"] == "test"]
    if not rows:
        return {}
    has_rate = any(r["method"] == "rate" for r in result["rows"])
    pairs: list[float] = []
    rated: list[float] = []
    per_material: dict[str, Any] = {}
    for m in materials(result, "test"):
        per = {lv: _ratio(result, m, lv, "sparsebtf") for lv in levels}
        rate = {lv: _ratio(result, m, lv, "rate") for lv in levels} if has_rate else {}
        at = get(result, material=m, method=METHOD, level=mid, set="test") or {}
        got = [v for v in per.values() if v is not None]
        pairs += got
        rated += [v for v in rate.values() if v is not None]
        per_material[m] = {
            "per_level": {str(lv): v for lv, v in per.items()},
            "ratio_geomean": gmean(got),
            "vs_rate_geomean": gmean(list(rate.values())) if rate else None,
            # the coder's own error: the tree's, and every point at the smaller size
            "std_ratio_geomean": gmean([_std_ratio(result, m, lv, "mse_std_coded")
                                        for lv in levels]),
            "small_std_ratio_geomean": gmean([_std_ratio(result, m, lv, "mse_std_small")
                                              for lv in levels]),
            "small_texel_share": at.get("small_texel_share"),
            "nodes": at.get("nodes"),
            "tree_figure": at.get("tree_figure"),
        }
    fractions = [r["material_bytes"] / r["budget_bytes"] for r in rows
                 if r.get("budget_bytes") and r.get("mse_rgb") is not None]  # fmt: skip
    bytes_ok = bool(fractions) and max(fractions) <= 1.0
    adaptive_s = sum(r.get("encode_seconds") or 0.0 for r in rows)
    fixed_s = sum(r.get("fixed_encode_seconds") or 0.0 for r in rows)
    time_ratio = adaptive_s / fixed_s if fixed_s else None
    g = gmean(pairs)
    lower = sum(v < 1 for v in pairs)
    sizes = sorted({int(p) for r in rows for p in (r.get("nodes") or {})}, reverse=True)
    size_text = " and ".join(f"{p}x{p}" for p in sizes) or "several sizes"
    out = {
        "claim": f"(beyond the paper, §5) adaptive patch sizes (a rate-distortion quadtree of "
                 f"{size_text} nodes) lower the error against fixed {sizes[0] if sizes else 10}"
                 f"x{sizes[0] if sizes else 10} patches at equal bytes",
        "rule": f"over every test material x level pair, MSE[{METHOD}] / MSE[sparsebtf] at the "
                "same per-material Table 4 bytes (the adaptive code's, tree bits included, at "
                f"most the reference's): geometric mean < {1 - MARGIN} supported, > "
                f"{1 + MARGIN} not supported (higher error), else no clear difference; an "
                "adaptive code above its budget voids it. Where rate control ran (the fixed "
                "size, one byte budget over all points), a supported verdict says whether "
                f"MSE[{METHOD}] / MSE[rate] is below {1 - MARGIN} too (else the gain is the "
                "bytes moved between points, which rate control has without the tree)",
        "ratio_geomean": g,
        "ratio_median": float(np.median(pairs)) if pairs else None,
        "pairs_lower": f"{lower}/{len(pairs)}",
        "per_level_geomean": {str(lv): gmean([v["per_level"][str(lv)]
                                              for v in per_material.values()])
                              for lv in levels},
        "materials_lower": f"{sum((v['ratio_geomean'] or 1) < 1 for v in per_material.values())}"
                           f"/{len(per_material)}",
        "vs_rate_geomean": gmean(rated),
        "pairs_lower_than_rate": f"{sum(v < 1 for v in rated)}/{len(rated)}" if rated else None,
        "small_std_ratio_geomean": gmean([v["small_std_ratio_geomean"]
                                          for v in per_material.values()]),
        "per_material": per_material,
        "bytes_max_fraction": max(fractions) if fractions else None,
        "encode_seconds": adaptive_s, "fixed_encode_seconds": fixed_s,
        "encode_time_ratio": time_ratio,
        "reference_level": mid,
        "tree_figure": _chosen_figure(per_material),
        "figure": f"MSE ratio {_fig(g)} (geo. mean of {len(pairs)} material x level pairs, "
                  f"median {_fig(float(np.median(pairs)) if pairs else None)}); lower on "
                  f"{lower}/{len(pairs)} pairs; vs rate control {_fig(gmean(rated))}; "
                  f"encode {_fig(time_ratio, '{:.1f}')}x the fixed encode's time",
        "verdict": adaptive_verdict(pairs, bytes_ok, rated if has_rate else None),
    }
    return {"adaptive_patches": out}


def _chosen_figure(per_material: dict[str, Any]) -> str | None:
    """The picture results.md shows: the most mixed tree at the reference level (its share of
    texels in smaller nodes nearest one half; the first such material on a tie)."""
    drawn = [(abs(v["small_texel_share"] - 0.5), i, v["tree_figure"])
             for i, v in enumerate(per_material.values())
             if v.get("tree_figure") and v.get("small_texel_share") is not None]  # fmt: skip
    return min(drawn)[2] if drawn else None


def adaptive_figures(result: dict[str, Any]) -> list[str]:
    """The run-folder paths of the pictures results.md shows (for ``bench report``'s copy)."""
    s = (result.get("summary") or {}).get("adaptive_patches") or {}
    return [s["tree_figure"]] if s.get("tree_figure") else []


def adaptive_section(result: dict[str, Any], summary: dict[str, Any], img: str = ""
                     ) -> list[str]:  # fmt: skip
    """results.md's section on adaptive patch sizes (none when the method did not run):
    per material the MSE ratio at every level, against rate control, the texels in smaller
    nodes; the encode time; the picture (``img``: the image folder's prefix, as elsewhere)."""
    s = summary.get("adaptive_patches")
    if not s:
        return []
    levels = list(s["per_level_geomean"])
    mid = s["reference_level"]
    body = []
    for m, v in s["per_material"].items():
        share = v["small_texel_share"]
        nodes = ", ".join(f"{n} of {p}x{p}" for p, n in (v["nodes"] or {}).items())
        body.append([m, *(_fig(v["per_level"][lv]) for lv in levels),
                     _fig(v["ratio_geomean"]), _fig(v["vs_rate_geomean"]),
                     _fig(v.get("small_std_ratio_geomean")),
                     "—" if share is None else f"{share:.0%}", nodes or "—"])  # fmt: skip
    body.append(["geo. mean", *(_fig(s["per_level_geomean"][lv]) for lv in levels),
                 _fig(s["ratio_geomean"]), _fig(s["vs_rate_geomean"]),
                 _fig(s.get("small_std_ratio_geomean")), "", ""])
    lines = [
        "", "## Adaptive patch sizes (beyond the paper, §5)", "",
        f"`{METHOD}` trains one ensemble per patch size (the reference's settings) and codes "
        "each test material with a rate-distortion quadtree (`encode --adaptive-patches`) at "
        "the reference's per-material Table 4 bytes at each level, tree bits included "
        f"(largest share of the budget used: {_fig(s['bytes_max_fraction'], '{:.4f}')}). "
        "MSE ratio adaptive / fixed per level (below 1: adaptive is better), its geometric "
        "mean over the levels, the same against rate control (the fixed size with one byte "
        "budget over all points: what is left beyond moving bytes between points), the "
        "coder's own error (standardised log-YUV, from the codes) with every point coded at "
        "the smaller size over the fixed code's, at the same coefficients per texel (above "
        "1: smaller patches alone cost error, so the tree splits only where its allocation "
        f"makes up for it), and at level {mid} the share of texels in smaller nodes and the "
        "nodes.", "",
        _table(["material", *(f"level {lv}" for lv in levels), "geo. mean",
                "vs rate control", "all smaller / fixed (coder's error)",
                f"texels in smaller nodes ({mid})", f"nodes ({mid})"], body), "",
        f"Encode time: {_fig(s['encode_seconds'], '{:.1f}')} s adaptive against "
        f"{_fig(s['fixed_encode_seconds'], '{:.1f}')} s for fixed-tau encodes of the same "
        f"levels on the same model ({_fig(s['encode_time_ratio'], '{:.1f}')}x; both one "
        "level at a time, the adaptive one codes every node of every size).",
    ]  # fmt: skip
    fig = s.get("tree_figure")
    if fig:
        png = f"{img}{fig.rsplit('/', 1)[-1]}" if img else fig
        lines += ["", f"The most mixed tree at level {mid}, node borders coloured by size:", "",
                  f"![adaptive tree]({png})"]
    return lines

"""The Markdown tables of a ``bench quality`` run (every cell from ``results.json`` rows).

* Table 2 shape: SparseBTF against its variants ([MHU19], per-channel standardisation, rate
  control) and every other method at equal per-material storage, MSE × 1e-4.
* Table 3 shape: SparseBTF(L) per test material; the comparison with the neural encodings
  (one table per storage matching) is :mod:`.claims3`'s.
* Table 5 shape: SparseBTF(L) against the methods of the Table-5 materials (per-material PCA
  at equal and at twice the bytes).
* True black, storage of every method, stored bytes against Table 4.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from .methods.base import PER_MATERIAL
from .rows import find as _find
from .rows import get as _get
from .rows import label as _label
from .rows import levels as _levels
from .rows import matching_of as _matching_of
from .rows import materials as _materials
from .rows import method_order as _method_order
from .rows import rows as _rows

__all__ = [
    "STORAGE_JSON", "fmt", "gmean", "label_with_matching", "markdown_table", "method_matchings",
    "stored_levels", "stored_section", "table2", "table3", "table5", "table_black",
    "table_storage", "table_stored",
]  # fmt: skip

#: ``benchmarks/bench_storage.py --json`` output beside a run's results.json (or in
#: ``docs/results/``): its per-level figures go into results.md's "stored bytes vs Table 4".
STORAGE_JSON = "storage.json"


def gmean(values: Sequence[float | None]) -> float | None:
    """Geometric mean of the positive finite values (None when there are none)."""
    v = [x for x in values if x is not None and x > 0 and np.isfinite(x)]
    return float(np.exp(np.mean(np.log(v)))) if v else None


_gmean = gmean


def fmt(x: float | None, scale: float = 1e4) -> str:
    """A table cell: ``x × scale`` to 3 significant digits (— for None)."""
    if x is None:
        return "—"
    v = x * scale
    return f"{v:.3g}" if abs(v) < 1000 else f"{v:,.0f}"


_fmt = fmt


def markdown_table(header: list[str], body: list[list[str]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(row) + " |" for row in body]
    return "\n".join(lines)


def label_with_matching(result: dict[str, Any], method: str, matching: str | None) -> str:
    """A method's label, with its matching when the run codes it under more than one."""
    name = _label(result, method)
    many = {_matching_of(r) for r in _rows(result, method=method) if "matching" in r}
    return f"{name} [{matching}]" if matching and len(many) > 1 else name


def table2(result: dict[str, Any]) -> str:
    """Table 2 shape: every method with test rows x test materials at equal per-material
    storage (SparseBTF(L)'s bytes on each material), MSE x 1e-4."""
    levels = _levels(result)
    mats = _materials(result, "test")
    methods = _method_order(result, "test")
    blocks = []
    for lv in levels:
        body = []
        for m in methods:
            vals = [(_find(result, PER_MATERIAL, 1, material=x, method=m, level=lv, set="test")
                     or {}).get("mse_rgb") for x in mats]  # fmt: skip
            if all(v is None for v in vals):
                continue
            body.append([_label(result, m)] + [_fmt(v) for v in vals] + [_fmt(_gmean(vals))])
        blocks.append(f"**Level {lv}** (SparseBTF({lv}) storage for every method)\n\n"
                      + markdown_table(["method", *mats, "geo. mean"], body))
    return "\n\n".join(blocks)


def table3(result: dict[str, Any]) -> str:
    """Table 3 shape: SparseBTF(L) (and rate control) per test material, MSE x 1e-4."""
    mats = _materials(result, "test")
    body = []
    for lv in _levels(result):
        for m, name in (("sparsebtf", "SparseBTF"), ("rate", "SparseBTF+RC")):
            vals = [(_get(result, material=x, method=m, level=lv, set="test") or {}).get(
                "mse_rgb") for x in mats]
            if any(v is not None for v in vals):
                body.append([f"{name} ({lv})"] + [_fmt(v) for v in vals])
    return markdown_table(["method", *mats], body)


def table5(result: dict[str, Any]) -> str:
    """Table 5 shape: SparseBTF against every method of the Table-5 materials, at each of
    their budget factors (PCA: equal and 2x bytes)."""
    mats = _materials(result, "table5")
    if not mats:
        return "_no Table-5 materials in this run_"
    body = []
    order = _method_order(result, "table5")
    for lv in _levels(result):
        ref = [_get(result, material=x, method=order[0], level=lv, set="table5") for x in mats]
        if all(r is None for r in ref):
            continue
        body.append([f"{_label(result, order[0])} ({lv})"]
                    + [_fmt((r or {}).get("mse_rgb")) for r in ref])  # fmt: skip
        for m in order[1:]:
            rs_m = _rows(result, method=m, level=lv, set="table5")
            for f in sorted({r.get("budget_factor", 1) for r in rs_m}):
                rs = [_find(result, None, f, material=x, method=m, level=lv, set="table5")
                      for x in mats]  # fmt: skip
                cells = [
                    "—" if r is None else _fmt(r.get("mse_rgb"))
                    + (f" (r={'/'.join(map(str, r['ranks']))})" if "ranks" in r else "")
                    for r in rs
                ]
                body.append([f"{_label(result, m)} {f:g}x bytes of ({lv})", *cells])
    return markdown_table(["method", *mats], body)


def table_black(result: dict[str, Any]) -> str:
    """True-black materials: MSE per level of each coding, largest value, error concentration."""
    levels = sorted({r["level"] for r in _rows(result, set="black")})
    body = []
    for m in _materials(result, "black"):
        for method in _method_order(result, "black"):
            rs = {r["level"]: r for r in _rows(result, material=m, method=method, set="black")}
            if not rs:
                continue
            first = next(iter(rs.values()))
            body.append([m, _label(result, method), f"{first.get('log_offset', 0):.3g}",
                         *[_fmt(rs[lv]["mse_rgb"]) if lv in rs else "—" for lv in levels],
                         f"{max(r['max_decoded'] / r['reference_max'] for r in rs.values()):.3g}x",
                         f"{100 * max(r['top_error_share'] for r in rs.values()):.0f} %"])
    return markdown_table(["material", "coding", "log offset", *[f"L{lv}" for lv in levels],
                           "largest / reference max", "worst 0.01 % share"], body)


def method_matchings(result: dict[str, Any], sets: tuple[str, ...]) -> list[tuple[str, str]]:
    """(method, matching) pairs with rows in ``sets``, in row order ('' for the reference)."""
    seen: list[tuple[str, str]] = []
    for r in result["rows"]:
        key = (r["method"], r.get("matching", ""))
        if r["set"] in sets and key not in seen:
            seen.append(key)
    return seen


def table_storage(result: dict[str, Any]) -> str:
    """Bytes per material and per-material compression ratio of every method and level."""
    body = []
    for lv in _levels(result):
        for m, matching in method_matchings(result, ("test", "table5")):
            rs = [r for r in _rows(result, method=m, level=lv)
                  if r.get("budget_factor", 1) == 1 and r.get("set") != "black"
                  and r.get("matching", "") == matching]  # fmt: skip
            if not rs:
                continue
            b = [r["material_bytes"] / np.prod(r["size"]) for r in rs]
            mse = [r["mse_rgb"] for r in rs]
            stored = [r["stored_codes_bytes"] / r["material_bytes"] for r in rs
                      if r.get("stored_codes_bytes") and r["material_bytes"]]
            ratio = [r.get("ratio_per_material") or np.nan for r in rs]
            body.append([f"{lv}", label_with_matching(result, m, matching), f"{np.mean(b):.2f}",
                         f"{np.mean(ratio):.0f}",
                         f"{np.mean(stored):.3f}" if stored else "—",
                         _fmt(_gmean(mse)), str(len(rs))])
    head = ["level", "method", "bytes / texel", "ratio (per material)",
            "stored codes / Table 4", "geo. mean MSE x1e-4", "n"]
    if all(row[4] == "—" for row in body):  # a run from before stored bytes were recorded
        head.pop(4)
        body = [row[:4] + row[5:] for row in body]
    return markdown_table(head, body)


def stored_levels(storage: dict[str, Any]) -> list[dict[str, Any]]:
    """Per level of a ``bench_storage.py`` result: Table 4's and the stored bytes per
    material (means), stored codes / Table 4 (geometric mean and largest), ratios at
    400×400 (Table 4's codes; the stored file)."""
    out = []
    for lv in storage["levels"]:
        rs = [r for r in storage["rows"] if r["level"] == lv]
        if not rs:
            continue
        out.append({
            "level": lv, "tau": "/".join(map(str, rs[0]["tau"])), "n": len(rs),
            "codes_vs_table4": float(np.exp(np.mean(np.log(
                [r["stored_codes_vs_table4"] for r in rs])))),
            "codes_vs_table4_max": max(r["stored_codes_vs_table4"] for r in rs),
            "table4_bytes": float(np.mean([r["table4_material_bytes"] for r in rs])),
            "stored_codes": float(np.mean([r["stored_codes_bytes"] for r in rs])),
            "stored_total": float(np.mean([r["stored_bytes"] for r in rs])),
            "ratio_table4_400": float(np.mean([r["ratio_table4_400"] for r in rs])),
            "ratio_stored_400": float(np.mean([r["ratio_stored_400"] for r in rs])),
        })  # fmt: skip
    return out


def table_stored(storage: dict[str, Any]) -> str:
    """The "stored bytes vs Table 4" rows of results.md, from a bench_storage result."""
    body = [[str(s["level"]), s["tau"], str(s["n"]), f"{s['table4_bytes']:,.0f}",
             f"{s['stored_codes']:,.0f}",
             f"{s['codes_vs_table4']:.3f} (max {s['codes_vs_table4_max']:.3f})",
             f"{s['stored_total']:,.0f}", f"{s['ratio_table4_400']:.0f}",
             f"{s['ratio_stored_400']:.0f}"]
            for s in stored_levels(storage)]  # fmt: skip
    return markdown_table(["level", "tau Y/U/V", "n", "Table 4 bytes", "stored codes",
                   "stored bytes vs Table 4", "stored file", "ratio 400x400, Table 4",
                   "ratio 400x400, stored file"], body)  # fmt: skip


def stored_section(result: dict[str, Any]) -> list[str]:
    storage = result.get("storage")
    if not storage:
        return []
    quick = " --quick" if storage.get("quick") else ""
    return [
        "", "## Stored bytes vs Table 4", "",
        f"From `python benchmarks/bench_storage.py{quick} --json` (stored as `{STORAGE_JSON}` "
        "beside `results.json`), not from this quality run: the benchmark's unseen materials "
        "and its 100x100 Table-5 carpet at the same levels, coded with the levels' fixed tau on "
        "the bundled `release` model (this run codes on the models it trains, whose codes may "
        "compress somewhat differently), written in coded-file schema 3 (each "
        "dictionary's locations once with a usage bit per point, values as byte planes, "
        "shuffle + deflate; docs/format.md §3). Per level: "
        "Table 4's per-material bytes (5 B per coefficient + 2 B per point and channel), the "
        "stored codes and their share of Table 4's, the whole file (codes, statistics, "
        "directions, header: everything a material stores), and the per-material ratio at "
        "400x400 (stored codes per point x 1600 + this file's statistics, directions, header).",
        "", table_stored(storage),
    ]


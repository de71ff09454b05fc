"""True black and high dynamic range: the codec on materials with exact zeros, at every level.

For each true-black material (``synth`` with ``black=True``: no inter-reflection, hard shadows,
no highlight compression; ``metal`` adds masked holes and a high dynamic range) this codes the
material on the bundled model at the benchmark's four levels, τ = (326, 24, 24), (885, 64, 64),
(2001, 145, 145), (4478, 324, 324), ε = 0, four ways:

* ``before``   — what the codec did before: log offset 1e-5, no bound;
* ``release``  — log offset 1e-5 (the authors' preprocessing) with the bound;
* ``auto``     — the default: the per-material log offset and the bound;
* ``floored``  — a copy floored at 1e-3 (every value at least 1e-3), coded like ``before``.

Every reconstruction is scored against the unfloored material: linear-RGB MSE, the largest
decoded value over the material's maximum, and the share of the squared error in the worst
0.01 % of values. The checks of the issue "Never a firework": MSE strictly decreasing over the
levels; level-32 MSE within 1.25x of the floored copy's; no value above 2x the maximum.

``--ab`` then codes the seven synthetic classes (their default variant, with a stray-light floor
and no exact zero) ``before`` and ``auto``, and prints the MSE ratio per level: what the new
default costs or gains where the old one had no trouble.

    python benchmarks/bench_black.py [--materials metal:20,carpet:40] [--ab] [--ab-size 30]
                                     [--json]
"""

from __future__ import annotations

import argparse
import itertools
import time
from dataclasses import replace
from typing import Any

import numpy as np

from _common import machine, peak_rss_bytes, report
from sparsebtf.codec import encode_levels
from sparsebtf.data.synth import MATERIAL_CLASSES, cached
from sparsebtf.evaluation.benchmark_set import FLOOR
from sparsebtf.evaluation.runner import floored
from sparsebtf.evaluation.scoring import score_many
from sparsebtf.runtime import coded_btf_view
from sparsebtf.storage.bundled import load_bundled

LEVELS = {16: (326, 24, 24), 32: (885, 64, 64), 64: (2001, 145, 145), 128: (4478, 324, 324)}
WAYS = ("before", "release", "auto", "floored")


def code_ways(btf: Any, model: Any, ways: tuple[str, ...]) -> dict[str, list[Any]]:
    """Decoded views of ``btf`` at every level, for each way of coding it."""
    out = {}
    for way in ways:
        src = floored(btf, FLOOR) if way == "floored" else btf
        rule = "auto" if way == "auto" else "release"
        coded = encode_levels(src, model, list(LEVELS.values()), eps=0.0,
                              allow_below_training=True, log_offset=rule, progress=False)
        if way in ("before", "floored"):  # no bound: the decoder as it was
            coded = [replace(c, stats=replace(c.stats, bound=None)) for c in coded]
        out[way] = [coded_btf_view(c) for c in coded]
        out[way + "_eps"] = coded[0].stats.log_offset
    return out


def measure(btf: Any, model: Any, ways: tuple[str, ...]) -> dict[str, Any]:
    t0 = time.perf_counter()
    views = code_ways(btf, model, ways)
    recs = [v for w in ways for v in views[w]]
    scores = iter(score_many(btf, recs, ssim_images=0, progress=False))
    res: dict[str, Any] = {}
    for w in ways:
        s = [next(scores) for _ in LEVELS]
        res[w] = {
            "log_offset": views[w + "_eps"],
            "mse": [x["mse_rgb"] for x in s],
            "max_over_peak": [x["max_decoded"] / x["reference_max"] for x in s],
            "top_error_share": [x["top_error_share"] for x in s],
        }
    data = btf.read(slice(None), slice(None), slice(None), slice(None))
    res["zeros"] = float(np.mean(data == 0))
    res["peak"] = float(data.max())
    res["seconds"] = time.perf_counter() - t0
    if "auto" in res and "floored" in res:
        mse = res["auto"]["mse"]
        res["checks"] = {
            "strictly_decreasing": all(b < a for a, b in itertools.pairwise(mse)),
            "level32_vs_floored": mse[1] / res["floored"]["mse"][1],
            "max_over_peak": max(res["auto"]["max_over_peak"]),
        }
    return res


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--materials", default="metal:20,carpet:20,metal:40,carpet:40",
                    help="true-black materials CLASS:SIZE, comma-separated (seed 12)")
    ap.add_argument("--ab", action="store_true",
                    help="also code the seven synthetic classes before/auto")
    ap.add_argument("--ab-size", type=int, default=30, help="texels per side of the A/B")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    model = load_bundled()
    out: dict[str, Any] = {"machine": machine(), "levels": LEVELS, "black": {}, "ab": {}}
    rows: list[tuple[str, Any]] = []
    for spec in args.materials.split(","):
        cls, size = spec.split(":")
        btf = cached(cls, int(size), "ubo2014", 12, black=True)
        r = measure(btf, model, WAYS)
        name = f"{cls}+black {size}x{size}"
        out["black"][name] = r
        rows.append((f"{name}", f"zeros {100 * r['zeros']:.1f} %, max {r['peak']:.3g}, "
                     f"{r['seconds']:.0f} s"))  # fmt: skip
        for w in WAYS:
            x = r[w]
            rows.append((f"  {w} (eps {x['log_offset']:.3g})",
                         "MSE " + " / ".join(f"{m:.3g}" for m in x["mse"])
                         + f"; largest {max(x['max_over_peak']):.3g}x max; worst 0.01 % "
                         f"{100 * max(x['top_error_share']):.0f} %"))  # fmt: skip
        c = r["checks"]
        rows.append(("  checks", f"decreasing {c['strictly_decreasing']}, level 32 / floored "
                     f"{c['level32_vs_floored']:.3f} (<= 1.25), largest "
                     f"{c['max_over_peak']:.3g}x (<= 2)"))  # fmt: skip
    if args.ab:
        for cls in MATERIAL_CLASSES:
            btf = cached(cls, args.ab_size, "ubo2014", 12)
            r = measure(btf, model, ("before", "auto"))
            ratio = [a / b for a, b in zip(r["auto"]["mse"], r["before"]["mse"], strict=True)]
            r["auto_over_before"] = ratio
            out["ab"][cls] = r
            rows.append((f"A/B {cls} {args.ab_size}x{args.ab_size}",
                         "MSE auto / before per level " + " / ".join(f"{v:.3f}" for v in ratio)
                         + f" (eps {r['auto']['log_offset']:.3g})"))  # fmt: skip
        allr = np.array([r["auto_over_before"] for r in out["ab"].values()])
        gm = np.exp(np.log(allr).mean(axis=0))
        out["ab_geomean"] = gm.tolist()
        rows.append(("A/B geometric mean", " / ".join(f"{v:.3f}" for v in gm)))
    out["peak_rss_bytes"] = peak_rss_bytes()
    rows.append(("peak memory", f"{out['peak_rss_bytes'] / 2**30:.2f} GiB"))
    report(rows, out, args.json)


if __name__ == "__main__":
    main()

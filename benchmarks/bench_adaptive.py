"""Adaptive patch sizes (issue 35, first slice): what the quadtree costs and what it picks, on
small synthetic materials with tiny direction sets (a smoke measurement, not the verdict:
that is ``bench quality``'s, a later slice).

Trains one model of two patch sizes (K = 2, every point, 3 iterations) on carpet, fabric
and wood, then codes unseen materials three ways at the same τ per texel: fixed at the
largest size, fixed at the smallest, and adaptive (the τ rule: at most the fixed
largest-size code's Table 4 bytes). Prints, per material and way, the Table 4 bytes (with
the tree), the MSE of linear RGB and of the standardised log-YUV values, the encode seconds
and the adaptive tree's nodes per size.

    python benchmarks/bench_adaptive.py [--size 20] [--patches 10,5] [--directions tiny13]
"""

from __future__ import annotations

import argparse
import json
import time
from typing import Any

import numpy as np

from sparsebtf.codec import encode, train
from sparsebtf.codec.adaptive import encode_adaptive
from sparsebtf.data.synth import cached
from sparsebtf.points.grid import parse_patches
from sparsebtf.runtime import coded_btf_view
from sparsebtf.runtime.adaptive import decoded_view
from sparsebtf.storage import storage_report
from sparsebtf.storage.adaptive_file import adaptive_report

TRAIN = ("carpet", "fabric", "wood")
TEST = ("felt", "stone", "wallpaper", "leather")


def _mse(ref: np.ndarray, view) -> float:
    return float(np.mean((view.to_array().astype(np.float64) - ref) ** 2))


def model_arguments(ap: argparse.ArgumentParser) -> None:
    """The options of the small model and its materials (shared with bench_adaptive_lookup)."""
    ap.add_argument("--size", type=int, default=20)
    ap.add_argument("--patches", default="10,5")
    ap.add_argument("--directions", default="tiny13")
    ap.add_argument("--tau", default="64,16,16", help="per point of the largest size")


def small_model(a: argparse.Namespace) -> Any:
    """K = 2, every point, 3 iterations, on :data:`TRAIN` at ``a.patches``."""
    return train([cached(c, a.size, a.directions, 1) for c in TRAIN], n_dictionaries=2,
                 tau_train=(16, 4, 4), patch=parse_patches(a.patches), sample=1.0, max_iter=3,
                 progress=False)  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    model_arguments(ap)
    a = ap.parse_args()
    sizes = parse_patches(a.patches)
    t = time.perf_counter()
    model = small_model(a)
    print(json.dumps({"train_seconds": round(time.perf_counter() - t, 1),
                      "patch_sizes": list(sizes)}))  # fmt: skip
    tau = [int(v) for v in a.tau.split(",")]
    small = [max(1, round(v * (sizes[-1] / sizes[0]) ** 2)) for v in tau]
    for cls in TEST:
        btf = cached(cls, a.size, a.directions, 7)
        ref = btf.to_array().astype(np.float64)
        rows = {}
        for way, run in (
            ("fixed_largest", lambda b=btf: encode(b, model, tau, progress=False)),
            ("fixed_smallest", lambda b=btf: encode(b, model.for_patch(sizes[-1]), small,
                                                    progress=False)),
            ("adaptive", lambda b=btf: encode_adaptive(b, model, tau, progress=False)),
        ):  # fmt: skip
            t = time.perf_counter()
            coded = run()
            seconds = time.perf_counter() - t
            if way == "adaptive":
                rep, view = adaptive_report(coded, model), decoded_view(coded)
                extra = {"nodes": coded.tree.counts()}
            else:
                rep, view = storage_report(coded, stored=False), coded_btf_view(coded)
                extra = {}
            rows[way] = {"table4_bytes": rep["bytes_table4_material"],
                         "mse_rgb": round(_mse(ref, view), 6),
                         "seconds": round(seconds, 2), **extra}  # fmt: skip
        print(json.dumps({"material": cls, **rows}))


if __name__ == "__main__":
    main()

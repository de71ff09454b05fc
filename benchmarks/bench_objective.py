"""Coding objectives (issue 32): the error of each storage level under ``--objective``
log / linear / display, on the bundled ``release`` model (K = 8, 10×10×151×151 points).

One BTF (a dense file, e.g. ``sparsebtf capture copper -o copper.h5 --size 40 --spp 1``, or a
``synth:`` spec) is coded at the benchmark's levels 16/32/64/128 (fixed τ per level from the
per-material ratio of the paper's SparseBTF(L), chroma at least τ_l; ε = 0) under each
objective, all levels from one pass (:func:`~sparsebtf.codec.encode_levels`). Per objective
and level: the MSE of linear RGB, of the display mapping (1.3·I^(1/1.8), clipped at 1) and of
ln(RGB + 1e-5) over every value; per objective the data points whose linear MSE rose from one
level to the next, and the encode time per point (wall clock, so on a loaded machine only
their ratio means much).

    python benchmarks/bench_objective.py BTF [--objectives log linear display]
                                         [--log-offset auto|release|OFFSET] [--json]
"""

from __future__ import annotations

import argparse
import time
from typing import Any

import numpy as np

from _common import machine, report
from sparsebtf.codec import encode_levels
from sparsebtf.display import tone_map
from sparsebtf.evaluation.benchmark_set import level_tau, paper_level_ratio
from sparsebtf.learning.objective import OBJECTIVES
from sparsebtf.open import open_btf
from sparsebtf.runtime.dense import DecodedBTF
from sparsebtf.storage.bundled import load_bundled

LEVELS = (16, 32, 64, 128)


def run(spec: str, objectives: list[str], log_offset: str) -> dict[str, Any]:
    model = load_bundled()
    btf = open_btf(spec)
    ref = btf.to_array().astype(np.float64)
    p = model.patch
    n_pts = (btf.height // p) * (btf.width // p)
    taus = [level_tau(2 * btf.n_values / paper_level_ratio(lv) / n_pts,
                      minimum=tuple(model.tau_train[c] for c in "YUV"))  # type: ignore[arg-type]
            for lv in LEVELS]  # fmt: skip
    out: dict[str, Any] = {
        "btf": spec, "texels": f"{btf.height}x{btf.width}", "points": n_pts,
        "zeros": float((ref == 0).mean()), "above_1": float((ref > 1).mean()),
        "max": float(ref.max()), "log_offset": log_offset, "taus": taus, "objectives": {},
    }  # fmt: skip
    ref_disp, ref_log = tone_map(ref), np.log(ref + 1e-5)
    for obj in objectives:
        t0 = time.perf_counter()
        coded = encode_levels(btf, model, taus, eps=0.0, log_offset=log_offset,
                              progress=False, objective=obj)  # fmt: skip
        secs = time.perf_counter() - t0
        rows, per_point = [], []
        for lv, c in zip(LEVELS, coded, strict=True):
            dec = DecodedBTF(c).to_array().astype(np.float64)
            err = (dec - ref) ** 2
            per_point.append(err.reshape(btf.height // p, p, btf.width // p, p, -1)
                             .mean(axis=(1, 3, 4)).ravel())  # fmt: skip
            rows.append({
                "level": lv, "mse_linear": float(err.mean()),
                "mse_display": float(((tone_map(dec) - ref_disp) ** 2).mean()),
                "mse_log": float(((np.log(np.maximum(dec, 0) + 1e-5) - ref_log) ** 2).mean()),
            })  # fmt: skip
        pp = np.array(per_point)
        out["objectives"][obj] = {
            "levels": rows, "seconds": secs, "seconds_per_point": secs / n_pts,
            "points_worse": [int((pp[i + 1] > pp[i]).sum()) for i in range(len(LEVELS) - 1)],
        }  # fmt: skip
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("btf")
    ap.add_argument("--objectives", nargs="+", choices=OBJECTIVES, default=list(OBJECTIVES))
    ap.add_argument("--log-offset", default="auto")
    ap.add_argument("--json", action="store_true")
    a = ap.parse_args()
    data = run(a.btf, a.objectives, a.log_offset)
    data["machine"] = machine()
    rows: list[tuple[str, str]] = [
        ("material", f"{data['btf']} ({data['texels']}, {data['points']} points): "
                     f"{data['zeros']:.1%} zeros, {data['above_1']:.1%} above 1, "
                     f"max {data['max']:.1f}; log offset {data['log_offset']}"),
    ]  # fmt: skip
    for obj, r in data["objectives"].items():
        lin = ", ".join(f"{x['mse_linear']:.4g}" for x in r["levels"])
        disp = ", ".join(f"{x['mse_display']:.4g}" for x in r["levels"])
        log = ", ".join(f"{x['mse_log']:.4g}" for x in r["levels"])
        rows.append((obj, f"linear MSE at {'/'.join(map(str, LEVELS))}: {lin}; display {disp}; "
                          f"log {log}; points worse than the level below {r['points_worse']}; "
                          f"{r['seconds_per_point']:.2f} s/point"))  # fmt: skip
    report(rows, data, a.json)


if __name__ == "__main__":
    main()

"""Cost (and a quick quality read-out) of the neural baselines at a benchmark configuration.

Fits and codes RGJW20, RGJW20 + fine-tuning, RJGW19 and NeuMIP (no offset) on the
configuration's training and test materials at every level under both storage matchings,
as ``sparsebtf bench quality`` would, and prints the wall time of each method. The MSE
(linear RGB, ×1e-4) is taken on ``--queries`` random (texel, light, view) points per material
through ``query`` — a sample, not the runner's full-grid score.

    python benchmarks/bench_neural.py --config quick [--methods rgjw20,rjgw19] [--json out]
"""

from __future__ import annotations

import argparse
import json
import os
import time

import numpy as np

from sparsebtf.evaluation.benchmark_set import BenchConfig
from sparsebtf.evaluation.methods import PAPER, PER_MATERIAL, Budget, FitContext, method_class

NAMES = ("rgjw20", "rgjw20+ft", "rjgw19", "neumip")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--config", choices=("quick", "full"), default="quick")
    ap.add_argument("--methods", default=",".join(NAMES))
    ap.add_argument("--queries", type=int, default=50_000)
    ap.add_argument("--json", default=None, help="write the rows here")
    args = ap.parse_args()
    cfg = BenchConfig.quick() if args.config == "quick" else BenchConfig()
    raw_per_texel = 2 * 3 * 151 * 151  # binary16 raw bytes per texel at UBO2014 directions
    bpt = {lv: raw_per_texel / r for lv, r in cfg.ratios().items()}
    context = FitContext(levels=cfg.levels, level_bytes_per_texel=bpt, config=cfg)
    t0 = time.perf_counter()
    train = [cfg.material(c, cfg.train_size, s) for c, s in cfg.train_set()]
    tests = [cfg.material(c, cfg.test_size, s) for c, s in cfg.test_set()]
    print(f"materials ready in {time.perf_counter() - t0:.1f} s; load {os.getloadavg()}")
    rows, times = [], {}
    for name in args.methods.split(","):
        method = method_class(name).from_config(cfg)
        t0 = time.perf_counter()
        method.fit(train, context)
        t_fit = time.perf_counter() - t0
        t_code = 0.0
        for btf in tests:
            hw = btf.height * btf.width
            budgets = [Budget(lv, 2 * lv * hw, PAPER) for lv in cfg.levels]
            budgets += [Budget(lv, int(bpt[lv] * hw), PER_MATERIAL) for lv in cfg.levels]
            t1 = time.perf_counter()
            codings = method.code(btf, budgets)
            t_code += time.perf_counter() - t1
            rng = np.random.default_rng(0)
            q = [rng.integers(0, n, args.queries) for n in btf.shape[:4]]
            full = btf.region(slice(None), slice(None))
            ref = np.maximum(full[q[0], q[1], q[2], q[3]], 0)
            for b, c in zip(budgets, codings, strict=True):
                mse = (float(np.mean((c.reconstruction.query(*q) - ref) ** 2)) * 1e4
                       if c.reconstruction is not None else None)  # fmt: skip
                size = c.info.get("latent_size", c.info.get("channels"))
                rows.append({"method": name, "material": btf.name, "level": b.level,
                             "matching": b.matching, "size": size, "bytes": c.material_bytes,
                             "budget": b.material_bytes, "mse_1e4": mse})  # fmt: skip
        times[name] = {"fit_s": round(t_fit, 1), "code_s": round(t_code, 1),
                       "total_s": round(t_fit + t_code, 1),
                       "training_budget": method.training_budget()}  # fmt: skip
        print(f"{name}: fit {t_fit:.1f} s, code {t_code:.1f} s (scoring excluded), "
              f"load {os.getloadavg()}", flush=True)  # fmt: skip
    print(f"total fit + code {sum(t['total_s'] for t in times.values()):.1f} s")
    for name in times:
        for matching in (PAPER, PER_MATERIAL):
            for lv in cfg.levels:
                sel = [r for r in rows if r["method"] == name and r["matching"] == matching
                       and r["level"] == lv and r["mse_1e4"] is not None]  # fmt: skip
                if sel:
                    print(f"  {name:10s} {matching:12s} level {lv:3d}: size {sel[0]['size']}, "
                          f"mean MSE x1e-4 {np.mean([r['mse_1e4'] for r in sel]):.1f}")
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"times": times, "rows": rows}, f, indent=1)


if __name__ == "__main__":
    main()

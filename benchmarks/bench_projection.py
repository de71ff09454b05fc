"""Projection throughput (Eq. 3) as a fraction of this machine's large fp32 GEMM, one run.

A projection of a 10×10×151×151 data point on one dictionary needs 2·L·Σm_n ≈ 1.47 GFLOP
(L = 2,280,100 entries). We time the coder's projection path (one point per worker, single-
threaded BLAS per worker) and, separately, the full coding step (projection + top-τ selection
on K = 8 dictionaries), and divide their useful GFLOP/s by a 4096² fp32 GEMM's, measured in the
same process. Target: projection >= 50% of GEMM.

    python benchmarks/bench_projection.py [--points 8] [--json]
"""

from __future__ import annotations

import argparse

import numpy as np

from _common import best_of, gemm_gflops, machine, report
from sparsebtf._threads import n_workers, parallel_map
from sparsebtf.learning.coding import sparse_code
from sparsebtf.learning.ensemble import random_orthonormal
from sparsebtf.learning.tensor import project


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--points", type=int, default=8, help="data points per timed batch")
    ap.add_argument("--shape", default="10,10,151,151")
    ap.add_argument("--dicts", type=int, default=8)
    ap.add_argument("--json", action="store_true")
    a = ap.parse_args()
    shape = tuple(int(s) for s in a.shape.split(","))
    rng = np.random.default_rng(0)
    x = rng.standard_normal((a.points, *shape)).astype(np.float32)
    dicts = [
        np.stack([random_orthonormal(m, rng) for _ in range(a.dicts)]).astype(np.float32)
        for m in shape
    ]
    size = int(np.prod(shape))
    flop = 2 * size * sum(shape)

    gemm = gemm_gflops()
    mats = [d[0] for d in dicts]

    def one(i: int) -> None:
        project(x[i : i + 1], mats)

    proj_s = best_of(lambda: list(parallel_map(one, range(a.points)))) / a.points
    proj_gf = flop / proj_s / 1e9

    code_s = best_of(lambda: sparse_code(x, dicts, 885, 1e-5)) / (a.points * a.dicts)
    code_gf = flop / code_s / 1e9
    gemm_after = gemm_gflops()
    gemm_ref = max(gemm, gemm_after)

    data = {
        "machine": machine(),
        "workers": n_workers(),
        "shape": shape,
        "gemm_gflops": gemm_ref,
        "projection_gflops": proj_gf,
        "projection_ms_per_point_dict": proj_s * 1e3,
        "projection_vs_gemm": proj_gf / gemm_ref,
        "coding_gflops": code_gf,
        "coding_ms_per_point_dict": code_s * 1e3,
        "coding_vs_gemm": code_gf / gemm_ref,
        "useful_gflop_per_projection": flop / 1e9,
    }
    report(
        [
            ("data point", "x".join(map(str, shape))),
            ("workers (1 BLAS thread each)", n_workers()),
            ("fp32 GEMM 4096^2 (GFLOP/s)", f"{gemm_ref:.1f}"),
            (
                "projection (GFLOP/s useful)",
                f"{proj_gf:.1f}  ({proj_s * 1e3:.1f} ms / point / dict)",
            ),
            ("projection / GEMM", f"{proj_gf / gemm_ref:.2f}  (target >= 0.50)"),
            ("coding: projection + top-885 (GFLOP/s)", f"{code_gf:.1f}  ({code_s * 1e3:.1f} ms)"),
            ("coding / GEMM", f"{code_gf / gemm_ref:.2f}"),
        ],
        data,
        a.json,
    )


if __name__ == "__main__":
    main()

"""Encoding a UBO2014-size BTF from a lazy low-rank source: wall time and peak memory.

The source is a 400×400×151×151 FactorBTF of rank 100 per channel in the log domain, the way
UBO2014 files store their data, so the 44 GB BTF is never in memory: statistics stream by
view block, data points by patch. The model is K = 8 random orthonormal dictionaries per
channel (the encoder's cost does not depend on training). τ = (885, 64, 64), ε = 1e-5.
Targets: <= 1060 s (the paper's figure; aim for half) and <= 4 GB peak on 2 cores.

    python benchmarks/bench_encode.py [--size 400] [--rank 100] [--json]

``--size 100`` runs a 100×100 crop (100 data points) and also prints the per-point rate.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from _common import machine, peak_rss_bytes, report
from sparsebtf.codec import encode
from sparsebtf.data.btf import FactorBTF
from sparsebtf.data.directions import ubo2014
from sparsebtf.learning.ensemble import random_orthonormal
from sparsebtf.model import CHANNELS, Model


def lazy_source(size: int, rank: int, seed: int = 0) -> FactorBTF:
    """Smooth angular factors and textured spatial factors, log domain (like UBO2014's SVD)."""
    rng = np.random.default_rng(seed)
    d = ubo2014()
    cos_l = d.xyz[:, 2][:, None]
    cos_v = d.xyz[:, 2][None, :]
    basis = [np.ones((151, 151)), np.log(cos_l + 0.05) + 0 * cos_v, np.log(cos_v + 0.1) + 0 * cos_l]
    ang = np.empty((3, 151 * 151, rank), np.float32)
    for c in range(3):
        for r in range(rank):
            if r < 3:
                a = basis[r]
            else:
                f = rng.normal(size=3)
                a = np.cos(f[0] * d.xyz[:, 0:1] * 3 + f[1] * d.xyz[:, 1][None, :] * 3 + f[2])
            ang[c, :, r] = a.ravel() / (1 + r)
    spatial = rng.normal(size=(3, size * size, rank)).astype(np.float32) * 0.05
    spatial[:, :, 0] = -1.5 + 0.3 * rng.random((3, 1))
    spatial[:, :, 1:3] = 1.0
    return FactorBTF(spatial, ang, size, size, d, d, log_domain=True, name=f"lazy{size}r{rank}")


def random_model(k: int, seed: int = 0) -> Model:
    rng = np.random.default_rng(seed)
    d = ubo2014()
    dicts = {
        ch: [np.stack([random_orthonormal(m, rng) for _ in range(k)]) for m in (10, 10, 151, 151)]
        for ch in CHANNELS
    }
    return Model(dicts, 10, d, d, {"tau_train": {"Y": 256, "U": 32, "V": 32}})


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", type=int, default=400)
    ap.add_argument("--rank", type=int, default=100)
    ap.add_argument("--dicts", type=int, default=8)
    ap.add_argument("--tau", default="885,64,64")
    ap.add_argument("--json", action="store_true")
    a = ap.parse_args()
    btf = lazy_source(a.size, a.rank)
    model = random_model(a.dicts)
    rss0 = peak_rss_bytes()
    t = time.perf_counter()
    coded = encode(btf, model, tau=a.tau, eps=1e-5)
    wall = time.perf_counter() - t
    n_points = coded.n_points
    full_points = 1600
    data = {
        "machine": machine(),
        "size": a.size,
        "rank": a.rank,
        "dicts": a.dicts,
        "tau": a.tau,
        "seconds": wall,
        "points": n_points,
        "seconds_per_point": wall / n_points,
        "projected_seconds_400x400": wall / n_points * full_points,
        "peak_rss_bytes": peak_rss_bytes(),
        "peak_rss_before_bytes": rss0,
        "nnz": coded.nnz(),
        "raw_btf_bytes_fp32": btf.n_values * 4,
    }
    report(
        [
            (
                "source",
                f"{a.size}x{a.size}x151x151 FactorBTF rank {a.rank} (never materialised: "
                f"{btf.n_values * 4 / 1e9:.1f} GB in fp32)",
            ),
            ("model", f"K = {a.dicts} per channel, tau = {a.tau}, eps = 1e-5"),
            ("wall time", f"{wall:.1f} s ({wall / n_points:.3f} s per data point)"),
            (
                "400x400 (1600 points)",
                f"{wall / n_points * full_points:.0f} s (paper: 1060 s; target <= 1060, aim 530)",
            ),
            ("peak memory (RSS)", f"{peak_rss_bytes() / 2**30:.2f} GiB (target <= 4 GB)"),
            ("nnz", coded.nnz()),
        ],
        data,
        a.json,
    )


if __name__ == "__main__":
    main()

"""Shared helpers of the benchmark scripts: timing, peak memory, reporting."""

from __future__ import annotations

import json
import platform
import resource
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from sparsebtf.data.directions import ubo2014
from sparsebtf.learning.coding import SparseCodes
from sparsebtf.learning.ensemble import random_orthonormal
from sparsebtf.model import CHANNELS, CodedBTF, Model
from sparsebtf.points.preprocessing import Standardization

#: The release's sparsity per channel, the level every rendering benchmark times.
TAU = {"Y": 885, "U": 64, "V": 64}


def best_of(fn: Callable[[], Any], repeat: int = 3) -> float:
    """Best wall time of ``repeat`` runs after one warm-up (seconds)."""
    fn()
    times = []
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return min(times)


def gemm_gflops(n: int = 4096, dtype: type = np.float32) -> float:
    """This machine's large square GEMM throughput (GFLOP/s), the reference of every ratio."""
    rng = np.random.default_rng(0)
    a = rng.standard_normal((n, n)).astype(dtype)
    b = rng.standard_normal((n, n)).astype(dtype)
    return 2 * n**3 / best_of(lambda: a @ b) / 1e9


def peak_rss_bytes() -> int:
    """Peak resident memory of this process so far."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024


def machine() -> dict[str, Any]:
    import os

    return {
        "python": platform.python_version(),
        "numpy": np.__version__,
        "cpus": len(os.sched_getaffinity(0)),
        "processor": platform.processor() or platform.machine(),
    }


def report(rows: list[tuple[str, Any]], data: dict[str, Any], as_json: bool) -> None:
    if as_json:
        print(json.dumps(data, indent=2, default=float))
        return
    width = max(len(k) for k, _ in rows)
    for k, v in rows:
        print(f"{k:<{width}}  {v}")


def synthetic_coded(
    size: int = 40, k: int = 8, tau: dict[str, int] | None = None, seed: int = 0
) -> CodedBTF:
    """A coded BTF at UBO2014 angular resolution for timing: K random orthonormal dictionaries
    per channel and τ random coefficients per point (distinct locations, sorted by decreasing
    magnitude as the encoder stores them). The cost of a lookup depends on τ, K and the angular
    size, not on the values."""
    tau = dict(tau or TAU)
    rng = np.random.default_rng(seed)
    d = ubo2014()
    shape = (10, 10, 151, 151)
    dicts = {
        ch: [np.stack([random_orthonormal(m, rng) for _ in range(k)]) for m in shape]
        for ch in CHANNELS
    }
    model = Model(dicts, 10, d, d, {"tau_train": tau})
    n_pts = (size // 10) ** 2
    codes = {}
    for ch in CHANNELS:
        t = tau[ch]
        lin = np.concatenate([rng.choice(int(np.prod(shape)), t, replace=False)
                              for _ in range(n_pts)])  # fmt: skip
        mag = np.sort(rng.exponential(1.0, (n_pts, t)), axis=1)[:, ::-1].ravel()
        vals = (mag * rng.choice([-1, 1], mag.size)).astype(np.float32)
        codes[ch] = SparseCodes(
            shape, rng.integers(0, k, n_pts).astype(np.uint8), np.full(n_pts, t),
            vals, np.stack(np.unravel_index(lin, shape), 1).astype(np.int32), np.zeros(n_pts),
        )  # fmt: skip
    stats = Standardization(
        "shared", rng.uniform(-1.5, -0.5, (151, 151, 1)), rng.uniform(0.3, 0.8, (151, 151, 1))
    )
    return CodedBTF(codes, stats, size, size, 10, d, d, model.content_hash, {"tau": tau},
                    f"synthetic{size}", {}, model)  # fmt: skip


def captured_coded(size: int = 30, seed: int = 0) -> CodedBTF:
    """The built-in woven sample captured at 1 spp (``sparsebtf capture woven``, cached) and
    coded with the bundled release model at τ = (885, 64, 64), every point at exactly τ
    (ε = 0): a real code's sparsity pattern, which the compiled lookup and the plugin's pair
    sums exploit (``synthetic_coded``'s random locations are their worst case)."""
    import sparsebtf as sb
    from sparsebtf.data.capture import cached_capture

    btf = cached_capture("woven", size, seed=seed, spp=1)
    return sb.encode(btf, target=(TAU["Y"], TAU["U"], TAU["V"]),
                     options=sb.EncodeOptions(eps=0.0, progress=False))  # fmt: skip


def cpu_seconds() -> float:
    """User + system CPU time of this process so far (every thread)."""
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def task_seconds(records: list[dict], name: str) -> list[float]:
    """Compute time of each task of ``name`` in a Dask task stream."""
    return [
        sum(s["stop"] - s["start"] for s in r["startstops"] if s["action"] == "compute")
        for r in records
        if f"-{name}-" in r["key"]
    ]


def small_job() -> tuple[Any, Any]:
    """The test suite's shapes: 16×16 texels, 13 directions, 4×4 patches, K = 3."""
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    from tests.conftest import smooth_btf, tiny_model

    return smooth_btf(7, size=16), tiny_model(1)


def pca_reconstructions(btf: Any, budgets: list[int], seed: int = 0
                        ) -> list[tuple[int, list[int], int, np.ndarray]]:  # fmt: skip
    """Per-material linear PCA of ``btf`` at each byte budget, fitted once at the largest:
    (budget, ranks per channel, bytes, the reconstruction as a dense array) per budget."""
    from sparsebtf.evaluation.baselines import (
        allocate_ranks,
        fit_pca,
        pca_bytes,
        pca_rank_for_budget,
        pca_reconstruction,
    )

    n_tex, n_ang = btf.height * btf.width, len(btf.lights) * len(btf.views)
    top = max(1, pca_rank_for_budget(max(budgets), n_tex, n_ang))
    fit = fit_pca(btf, top, domain="linear", seed=seed, progress=False)
    out = []
    for b in budgets:
        ranks = allocate_ranks(fit, pca_rank_for_budget(b, n_tex, n_ang))
        out.append((int(b), list(ranks), pca_bytes(ranks, n_tex, n_ang),
                    pca_reconstruction(fit, ranks, btf).to_array()))
    return out

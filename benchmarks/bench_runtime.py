"""Runtime lookups (§3.4): lookups per second, Eq. 6 vs four lookups, vs a dense table.

A coded BTF at UBO2014 resolution (151 lights × 151 views, 10×10 patches, 40×40 texels) with
K = 8 random orthonormal dictionaries per channel and τ = (885, 64, 64) random coefficients
(sorted by magnitude as the encoder stores them). The cost of a lookup depends on τ, K and
the angular size, not on the texture size. Queries: random uv and random directions on the
upper hemisphere. Everything is measured in one run on this machine:

* lookups/s, nearest bin (Eq. 5), at τ and at τ' = τ/4 (run-time level of detail);
* lookups/s with 2×2 bilinear interpolation in coefficient space (Eq. 6), and the same result
  from four separate lookups blended afterwards: the speedup of Eq. 6 (paper: 4×);
* the NumPy path against the compiled (numba) one;
* a dense uncompressed table (20×20×151×151×3 float32, 109 MB) with the same 2×2
  interpolation: the memory-bound reference.

    python benchmarks/bench_runtime.py [--queries 200000] [--json]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from _common import TAU, best_of, machine, report, synthetic_coded
from sparsebtf.runtime import RuntimeBTF, angular_weights, kernels


def hemisphere(rng: np.random.Generator, n: int) -> np.ndarray:
    el = np.arcsin(rng.uniform(0.05, 1.0, n))
    az = rng.uniform(-np.pi, np.pi, n)
    return np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], axis=1)


def dense_lookup(table, row, col, li, lw, vi, vw):
    """2×2 interpolated lookup in a dense (H, W, L, V, 3) table (numba when present)."""
    if kernels.HAVE_NUMBA:
        return _dense_nb(table, row, col, li, lw, vi, vw)
    out = np.zeros((row.size, 3))
    for a in range(li.shape[1]):
        for b in range(vi.shape[1]):
            out += (lw[:, a] * vw[:, b])[:, None] * table[row, col, li[:, a], vi[:, b]]
    return out


if kernels.HAVE_NUMBA:
    import numba as nb

    @nb.njit(parallel=True, cache=True)
    def _dense_nb(table, row, col, li, lw, vi, vw):
        n = row.shape[0]
        out = np.zeros((n, 3))
        for q in nb.prange(n):
            for a in range(li.shape[1]):
                for b in range(vi.shape[1]):
                    w = lw[q, a] * vw[q, b]
                    for c in range(3):
                        out[q, c] += w * table[row[q], col[q], li[q, a], vi[q, b], c]
        return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--queries", type=int, default=200_000)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    n = args.queries
    coded = synthetic_coded()
    rt = RuntimeBTF(coded)
    quarter = {ch: t // 4 for ch, t in TAU.items()}
    rng = np.random.default_rng(1)
    uv = rng.uniform(0, 1, (n, 2))
    wi, wo = hemisphere(rng, n), hemisphere(rng, n)
    backend = "numba" if kernels.HAVE_NUMBA else "numpy"
    rate: dict[str, float] = {}

    def lookups(**kw) -> float:
        return n / best_of(lambda: rt.evaluate(wi, wo, uv=uv, backend=backend, **kw), 2)

    rate["nearest_tau"] = lookups(interpolation="nearest")
    rate["nearest_quarter"] = lookups(interpolation="nearest", tau=quarter)
    rate["eq6_linear_tau"] = lookups(interpolation="linear")
    rate["eq6_linear_quarter"] = lookups(interpolation="linear", tau=quarter)
    rate["log_domain_linear_tau"] = lookups(interpolation="linear", domain="log")
    rate["gaussian4_tau"] = lookups(interpolation="gaussian")

    # The NumPy path on a tenth of the queries (it pads every point to the widest count).
    m = max(n // 10, 1)
    rate["eq6_linear_tau_numpy"] = m / best_of(
        lambda: rt.evaluate(wi[:m], wo[:m], uv=uv[:m], backend="numpy"), 2
    )

    # Four separate lookups (one per bin pair) blended afterwards, vs one Eq. 6 sum.
    li, lw = angular_weights(coded.lights, wi, "linear")
    vi, vw = angular_weights(coded.views, wo, "linear")
    lights, views = coded.lights.xyz, coded.views.xyz

    def four_lookups() -> np.ndarray:
        acc = np.zeros((n, 3), np.float32)
        for a in range(2):
            for b in range(2):
                rgb = rt.evaluate(lights[li[:, a]], views[vi[:, b]], uv=uv,
                                  interpolation="nearest", backend=backend)  # fmt: skip
                acc += (lw[:, a] * vw[:, b])[:, None].astype(np.float32) * rgb
        return acc

    rate["four_lookups_tau"] = n / best_of(four_lookups, 2)

    # Kernel only (the sparse sums, without neighbour search and colour conversion).
    pts = np.arange(n) % coded.n_points
    i1 = (np.arange(n) // 7) % 10
    i2 = (np.arange(n) // 3) % 10
    ch = rt._channels["Y"]
    one = np.ones((n, 1))
    t_eq6 = best_of(lambda: kernels.separable_sum(ch, pts, i1, i2, li, lw, vi, vw, 885, backend), 2)

    def four_sums() -> None:
        for a in range(2):
            for b in range(2):
                kernels.separable_sum(ch, pts, i1, i2, li[:, a : a + 1], one,
                                      vi[:, b : b + 1], one, 885, backend)  # fmt: skip

    t_four = best_of(four_sums, 2)

    # Dense uncompressed reference: 20×20 texels, 151×151, RGB float32.
    table = rng.uniform(0, 1, (20, 20, 151, 151, 3)).astype(np.float32)
    row = (uv[:, 1] * 20).astype(np.int64)
    col = (uv[:, 0] * 20).astype(np.int64)
    t_dense = best_of(lambda: dense_lookup(table, row, col, li, lw, vi, vw), 2)
    t0 = time.perf_counter()
    angular_weights(coded.lights, wi, "linear")
    angular_weights(coded.views, wo, "linear")
    t_nn = time.perf_counter() - t0
    rate["dense_table_linear_lookup_only"] = n / t_dense
    rate["dense_table_linear_with_neighbour_search"] = n / (t_dense + t_nn)

    data = {
        "machine": machine(),
        "backend": backend,
        "queries": n,
        "tau": TAU,
        "quarter": quarter,
        "lookups_per_second": rate,
        "ratios": {
            "eq6_vs_four_lookups_end_to_end": rate["eq6_linear_tau"] / rate["four_lookups_tau"],
            "eq6_vs_four_sums_kernel_only_Y": t_four / t_eq6,
            "numba_vs_numpy_eq6": rate["eq6_linear_tau"] / rate["eq6_linear_tau_numpy"],
            "quarter_vs_full_tau_nearest": rate["nearest_quarter"] / rate["nearest_tau"],
            "quarter_vs_full_tau_eq6": rate["eq6_linear_quarter"] / rate["eq6_linear_tau"],
            "sparse_eq6_vs_dense_table": rate["eq6_linear_tau"]
            / rate["dense_table_linear_with_neighbour_search"],
            "sparse_eq6_quarter_vs_dense_table": rate["eq6_linear_quarter"]
            / rate["dense_table_linear_with_neighbour_search"],
        },
        "neighbour_search_seconds": t_nn,
        "kernel_seconds_Y": {"eq6": t_eq6, "four_sums": t_four},
    }
    rows = [(f"lookups/s {k}", f"{v:,.0f}") for k, v in rate.items()]
    rows += [(f"ratio {k}", f"{v:.2f}") for k, v in data["ratios"].items()]
    rows.append(("neighbour search (both directions)", f"{t_nn:.3f} s for {n} queries"))
    report(rows, data, args.json)


if __name__ == "__main__":
    main()

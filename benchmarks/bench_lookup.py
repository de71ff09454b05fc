"""Where a renderer's lookup spends its time: SparseBTF's Eq. 5/6 against the neural decoders
and against this machine's gather/FMA floor, all in one run on the same queries.

The materials (``--materials``), both at UBO2014 angular resolution (151 × 151 directions,
10 × 10 patches, ``--size`` texels square) and the release's τ = (885, 64, 64), SparseBTF(32):

* ``captured``: the built-in woven sample captured by ``sparsebtf capture`` (1 spp, cached)
  and coded with the bundled release model, every point at exactly τ (ε = 0): the columns
  a real code uses, which the lookup's compact factors exploit (``runtime/compact.py``);
* ``synthetic``: K = 8 random orthonormal dictionaries per channel and τ coefficients per
  point at random locations — the worst case for the compact factors (a point uses almost
  every column), which no encoder produces.

Queries (seeded): renderer-style — texels anywhere, continuous light and view directions
on the upper hemisphere — in three orders:

* ``random``: as they come;
* ``wavefront``: the same queries sorted by data point (a wavefront renderer's batch);
* ``brdf``: one texel, many directions (an apparent BRDF).

Timed, per material and order (queries/s, best of ``--repeat`` calls of ``--queries``):

* ``RuntimeBTF.evaluate`` (numba; every interpolation scheme), and for the two release
  schemes the previous lookup, rebuilt from the same kernels (a search of all directions per
  query, one query at a time, NumPy after the sums): the speed-up of this release;
* interpolation of decoded values instead of coefficients (§3.4's claim: about 4× the frame
  rate for Eq. 6): each query decoded by the same lookup at its 2 × 2 neighbouring measured
  direction pairs, then blended;
* the benchmark's neural decoders (PyTorch, ``NeuralBTF.lookup``: [code, ω_i.xy, ω_o.xy] →
  MLP, the widths of RJGW19, RGJW20 and NeuMIP, code size ``--latents``) on the same inputs;
* two floors (numba microkernels over the material's own coefficients, tables prebuilt and
  not timed): a sum of Eq. 5's terms one query at a time (four gathers and four multiplies
  per coefficient) and the same terms summed across 32 queries of a point at once (contiguous
  vector loads). A lookup cannot beat the floor of its loop without skipping coefficients.

Per query it reports the coefficients summed, the factor entries built (the compact lists'
lengths summed over Y, U and V, light and view rows once per neighbour), and cycles per query
at ``--ghz`` (default: the first CPU's clock) × the threads.

    python benchmarks/bench_lookup.py [--size 30] [--materials captured,synthetic]
                                      [--queries 65536] [--repeat 5] [--json]
"""

from __future__ import annotations

import argparse
import itertools
import os

import numpy as np

from _common import TAU, best_of, captured_coded, machine, report, synthetic_coded
from sparsebtf.colour import yuv_to_rgb
from sparsebtf.points.preprocessing import inverse_log_transform
from sparsebtf.runtime import RuntimeBTF, angular_weights, kernels
from sparsebtf.runtime.grouping import GROUP, group_by_point

SCHEMES = ("nearest", "linear", "barycentric", "gaussian")


def hemisphere(rng: np.random.Generator, n: int) -> np.ndarray:
    el = np.arcsin(rng.uniform(0.05, 1.0, n))
    az = rng.uniform(-np.pi, np.pi, n)
    return np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], axis=1)


def queries(rt: RuntimeBTF, n: int, seed: int) -> dict[str, tuple[np.ndarray, ...]]:
    """(texel (n, 2), wi, wo) per order."""
    rng = np.random.default_rng(seed)
    h, w = rt.coded.height, rt.coded.width
    tex = np.stack([rng.integers(0, h, n), rng.integers(0, w, n)], axis=1)
    wi, wo = hemisphere(rng, n), hemisphere(rng, n)
    pts, _, _ = rt._texels(None, tex, n)
    order = np.argsort(pts, kind="stable")
    one = np.broadcast_to(tex[:1], tex.shape).copy()
    return {"random": (tex, wi, wo), "wavefront": (tex[order], wi[order], wo[order]),
            "brdf": (one, wi, wo)}  # fmt: skip


def decoded_then_blended(rt: RuntimeBTF, wi, wo, texel) -> np.ndarray:
    """Linear interpolation of decoded values instead of Eq. 6's coefficient space: each query
    decoded at its 2 × 2 neighbouring measured (light, view) pairs by the same compiled lookup
    (nearest, at the sampled directions themselves), then blended in the log domain with the
    release's weights — what interpolating a decoded table costs with this runtime. Equal to
    ``evaluate(..., domain="log")`` but where the bound clamps (here each decoded value, there
    the blend)."""
    li, lw = rt._weights("lights", wi, "linear", None, 20.0, True)  # the runtime's own search
    vi, vw = rt._weights("views", wo, "linear", None, 20.0, True)
    n = wi.shape[0]
    a, b = np.meshgrid(np.arange(2), np.arange(2), indexing="ij")
    a, b = a.ravel(), b.ravel()
    lights = rt.coded.lights.xyz[li[:, a].ravel()]
    views = rt.coded.views.xyz[vi[:, b].ravel()]
    vals = rt.evaluate(lights, views, texel=np.repeat(texel, 4, axis=0), interpolation="nearest")
    w = (lw[:, a] * vw[:, b])[:, :, None]
    log = np.log(vals.reshape(n, 4, 3) + rt.log_offset)
    return np.exp(np.sum(w * log, axis=1)) - rt.log_offset


def previous_evaluate(rt: RuntimeBTF, wi, wo, texel, scheme: str) -> np.ndarray:
    """The lookup before the grouped loop: a scan of all directions per query, the numba sum
    one query at a time, then NumPy (statistics, colour, bound, exp)."""
    pts, i1, i2 = rt._texels(None, texel, wi.shape[0])
    li, lw = angular_weights(rt.coded.lights, wi, scheme)
    vi, vw = angular_weights(rt.coded.views, wo, scheme)
    w2 = lw[:, :, None] * vw[:, None, :]
    mu = rt._mean[:, li[:, :, None], vi[:, None, :]]
    sd = rt._std[:, li[:, :, None], vi[:, None, :]]
    log = np.empty((pts.size, 3))
    for c, ch in enumerate("YUV"):
        si = c if rt._mean.shape[0] == 3 else 0
        x = kernels.separable_sum(rt._channels[ch], pts, i1, i2, li, lw, vi, vw, rt.tau[ch],
                                  "numba")  # fmt: skip
        log[:, c] = x * np.einsum("nab,nab->n", w2, sd[si]) + np.einsum("nab,nab->n", w2, mu[si])
    return inverse_log_transform(yuv_to_rgb(log), rt.log_offset).astype(np.float32)


def neural_decoders(size: int, latents: int, seed: int) -> dict:
    from sparsebtf.data.directions import ubo2014
    from sparsebtf.evaluation.neural._torch import NeuralBTF

    rng = np.random.default_rng(seed)
    d = ubo2014()
    out = {}
    for name, hidden, outputs, head, slope in (
        ("RJGW19", (32, 32, 32), 3, "log1p", 0.01),
        ("RGJW20", (64, 64, 64), 3, "log1p", 0.01),
        ("NeuMIP", (25, 25, 25), 6, "neumip", 0.0),
    ):
        dims = [latents + 4, *hidden, outputs]
        layers = [(rng.normal(0, 1 / np.sqrt(i), (o, i)), rng.normal(0, 0.1, o))
                  for i, o in itertools.pairwise(dims)]  # fmt: skip
        out[f"{name} decoder {'-'.join(map(str, dims))}"] = NeuralBTF(
            rng.normal(0, 1, (size, size, latents)), layers, d, d, head=head, slope=slope)
    return out


if kernels.HAVE_NUMBA:
    from sparsebtf._numba import numba as nb

    @nb.njit(parallel=True, fastmath=True, cache=True)
    def _floor_query(vals, locs, offs, pts, t1, t2, r3, r4, tau):
        # Eq. 5's terms one query at a time from prebuilt L1 tables: 4 gathers, 4 multiplies.
        n = pts.shape[0]
        out = np.empty(n, dtype=np.float32)
        for q in nb.prange(n):
            p = pts[q]
            s0 = offs[p]
            s1 = min(offs[p + 1], s0 + tau)
            b = (q & 7) * 256
            acc = np.float32(0.0)
            for s in range(s0, s1):
                c = locs[s]
                acc += (vals[s] * t1[b + (c & 0xFF)] * t2[b + ((c >> 8) & 0xFF)]
                        * r3[b + ((c >> 16) & 0xFF)] * r4[b + (c >> 24)])  # fmt: skip
            out[q] = acc
        return out

    @nb.njit(parallel=True, fastmath=True, cache=True)
    def _floor_lanes(vals, locs, offs, pts, order, starts, t1, t2, r3, r4, tau, width):
        # The same terms for a group of queries of one point across lanes (tables prebuilt).
        n = pts.shape[0]
        out = np.empty(n, dtype=np.float32)
        for g in nb.prange(starts.shape[0] - 1):
            q0 = starts[g]
            m = starts[g + 1] - q0
            p = pts[order[q0]]
            s0 = offs[p]
            s1 = min(offs[p + 1], s0 + tau)
            acc = np.zeros(width, dtype=np.float32)
            for s in range(s0, s1):
                c = locs[s]
                v = vals[s]
                o1 = (c & 0xFF) * width
                o2 = ((c >> 8) & 0xFF) * width
                o3 = ((c >> 16) & 0xFF) * width
                o4 = (c >> 24) * width
                for j in range(m):
                    acc[j] += v * t1[o1 + j] * t2[o2 + j] * r3[o3 + j] * r4[o4 + j]
            for j in range(m):
                out[order[q0 + j]] = acc[j]
        return out


def floors(rt: RuntimeBTF, texel: np.ndarray, repeat: int) -> dict[str, float]:
    """Queries/s of the two microkernels over all three channels' coefficients."""
    n = texel.shape[0]
    pts, _, _ = rt._texels(None, texel, n)
    rng = np.random.default_rng(0)
    tab = rng.uniform(0.5, 1.5, 256 * max(8, GROUP)).astype(np.float32)
    order, starts = group_by_point(pts, rt.coded.n_points, GROUP)
    t_query = t_lanes = 0.0
    for ch in "YUV":
        a = rt._channels[ch]
        args = (a["values"], a["locations"], a["offsets"], pts)
        tau = int(rt.tau[ch])
        t_query += best_of(lambda: _floor_query(*args, tab, tab, tab, tab, tau), repeat)  # noqa: B023
        t_lanes += best_of(lambda: _floor_lanes(*args, order, starts, tab, tab, tab, tab, tau,  # noqa: B023
                                                GROUP), repeat)  # fmt: skip
    return {"per query": n / t_query, "lanes": n / t_lanes}


def per_query_cost(rt: RuntimeBTF, kl: int, kv: int) -> tuple[float, float]:
    """(coefficients summed, factor entries built) per query, averaged over the points: the
    compact lists of every channel (pairs, kl light rows, kv view rows; ``runtime/compact``);
    the lookup before them built 2 + 2 + kl·151 + kv·151 entries per channel."""
    coef = entries = 0.0
    for ch in "YUV":
        off = rt._channels[ch]["offsets"]
        coef += float(np.mean(np.minimum(np.diff(off), rt.tau[ch])))
        n12, n3, n4 = rt._layout(ch).mean_sizes()
        entries += n12 + kl * n3 + kv * n4
    return coef, entries


def material(kind: str, size: int, seed: int) -> RuntimeBTF:
    """The benchmark's coded material ``kind`` ("captured" or "synthetic"), SparseBTF(32)."""
    if kind == "synthetic":
        return RuntimeBTF(synthetic_coded(size=size, tau=TAU, seed=seed))
    if kind != "captured":
        raise SystemExit(f"unknown material {kind!r}: captured or synthetic")
    return RuntimeBTF(captured_coded(size, seed))


def _ghz() -> float:
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("cpu MHz"):
                    return float(line.split(":")[1]) / 1000
    except OSError:
        pass
    return float("nan")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", type=int, default=30, help="texels square (multiple of 10)")
    ap.add_argument("--materials", default="captured,synthetic",
                    help="comma-separated: captured, synthetic")  # fmt: skip
    ap.add_argument("--queries", type=int, default=65536)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--latents", type=int, default=12, help="neural code size per texel")
    ap.add_argument("--ghz", type=float, default=None, help="clock for cycles (default: cpuinfo)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    if not kernels.HAVE_NUMBA:
        raise SystemExit("bench_lookup needs numba (pip install numba)")
    import torch

    threads = len(os.sched_getaffinity(0))
    torch.set_num_threads(threads)
    ghz = args.ghz or _ghz()
    nets = neural_decoders(args.size, args.latents, args.seed)
    n = args.queries

    def rate(fn) -> float:
        return n / best_of(fn, args.repeat)

    res: dict[str, dict[str, dict[str, float]]] = {}
    cost: dict[str, dict[str, float]] = {}
    for kind in args.materials.split(","):
        rt = material(kind, args.size, args.seed)
        qs = queries(rt, n, args.seed)
        rt.evaluate(*qs["random"][1:], texel=qs["random"][0])  # compile, build the lists
        coef, entries = per_query_cost(rt, 2, 2)
        cost[kind] = {"coefficients": coef, "factor_entries_linear": entries}
        res[kind] = {}
        for order, (tex, wi, wo) in qs.items():
            r: dict[str, float] = {}
            q = {"texel": tex, "wi": wi, "wo": wo}
            for scheme in SCHEMES:
                r[f"SparseBTF {scheme}"] = rate(
                    lambda s=scheme, q=q, rt=rt: rt.evaluate(q["wi"], q["wo"], texel=q["texel"],
                                                      interpolation=s))  # fmt: skip
            for scheme in ("nearest", "linear"):
                r[f"previous lookup {scheme}"] = rate(
                    lambda s=scheme, q=q, rt=rt: previous_evaluate(rt, q["wi"], q["wo"], q["texel"],
                                                            s))  # fmt: skip
            r["decoded values blended (2x2 nearest)"] = rate(
                lambda q=q, rt=rt: decoded_then_blended(rt, q["wi"], q["wo"], q["texel"]))
            for label, net in nets.items():
                r[label] = rate(lambda m=net, q=q: m.lookup(q["texel"][:, 0], q["texel"][:, 1],
                                                            q["wi"], q["wo"]))  # fmt: skip
            fl = floors(rt, tex, args.repeat)
            r["floor: gather/FMA per query"] = fl["per query"]
            r[f"floor: {GROUP} lanes per point"] = fl["lanes"]
            res[kind][order] = r
    best_neural = {k: {o: max(v for lab, v in r.items() if "decoder" in lab)
                       for o, r in per.items()} for k, per in res.items()}  # fmt: skip
    rows: list[tuple[str, str]] = [
        ("materials", f"{args.size}x{args.size} texels, 151x151 directions, tau "
                      f"{TAU['Y']}/{TAU['U']}/{TAU['V']}, float32; {threads} threads, "
                      f"{ghz:.2f} GHz"),
    ]  # fmt: skip
    for kind, per in res.items():
        rows.append((f"== {kind}", f"{cost[kind]['coefficients']:.0f} coefficients, "
                     f"{cost[kind]['factor_entries_linear']:.0f} factor entries per linear "
                     "query"))  # fmt: skip
        for order, r in per.items():
            rows.append((f"-- {order} ({n} queries)", "queries/s   cycles/query   "
                         "vs best neural   vs lane floor"))  # fmt: skip
            for label, v in r.items():
                cyc = threads * ghz * 1e9 / v
                rows.append((f"  {label}", f"{v / 1e6:7.2f} M   {cyc:10,.0f}   "
                             f"{v / best_neural[kind][order]:10.2f}x   "
                             f"{v / r[f'floor: {GROUP} lanes per point']:8.2f}x"))  # fmt: skip
    report(rows, {"machine": machine(), "threads": threads, "ghz": ghz, "queries": n,
                  "size": args.size, "tau": TAU, "latents": args.latents,
                  "per_query": cost, "queries_per_second": res, "best_neural": best_neural},
           args.json)  # fmt: skip


if __name__ == "__main__":
    main()

"""The Mitsuba plugin's lookup on a material coded with adaptive patch sizes against the same
material coded at the largest size (a smoke timing on small synthetic materials).

Trains one model of two patch sizes (K = 2, 3 iterations) on carpet, fabric and wood (as
``bench_adaptive.py``), codes an unseen material fixed at the largest size and adaptively at
the same τ (the τ rule: at most the fixed code's Table 4 bytes), then times the ``sparsebtf``
plugin's ``eval`` (llvm variant, level of detail off) on ``--queries`` random shading points:
the process's CPU time (all of Dr.Jit's threads, less disturbed by other load than the wall
time), best of ``--repeat`` interleaved rounds after one call that compiles the kernels.
Prints per way the CPU time per lookup, the coefficients a lookup reads (Y + U + V, counted
with ``lod_stats``) and the CPU time per coefficient read.

    python benchmarks/bench_adaptive_lookup.py [--size 20] [--patches 10,5] [--material wallpaper]
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from bench_adaptive import model_arguments, small_model
from sparsebtf.codec import encode
from sparsebtf.codec.adaptive import encode_adaptive
from sparsebtf.data.synth import cached
from sparsebtf.points.grid import parse_patches
from sparsebtf.runtime import AdaptiveRuntimeBTF, RuntimeBTF


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    model_arguments(ap)
    ap.add_argument("--material", default="wallpaper")
    ap.add_argument("--queries", type=int, default=1 << 18)
    ap.add_argument("--repeat", type=int, default=5)
    a = ap.parse_args()
    import sparsebtf.mitsuba as sbm

    sbm.setup("llvm")
    import drjit as dr
    import mitsuba as mi

    sizes = parse_patches(a.patches)
    model = small_model(a)
    tau = [int(v) for v in a.tau.split(",")]
    btf = cached(a.material, a.size, a.directions, 7)
    ways = {"fixed": RuntimeBTF(encode(btf, model, tau, progress=False)),
            "adaptive": AdaptiveRuntimeBTF(encode_adaptive(btf, model, tau, progress=False))}
    rng = np.random.default_rng(0)
    n = a.queries

    def dirs() -> np.ndarray:
        v = rng.normal(size=(n, 3))
        v[:, 2] = np.abs(v[:, 2]) + 0.1
        return (v / np.linalg.norm(v, axis=1, keepdims=True)).astype(np.float32)

    wi, wo = dirs(), dirs()
    uv = rng.uniform(0, 1, (n, 2)).astype(np.float32)
    si = dr.zeros(mi.SurfaceInteraction3f, n)
    si.wi, si.uv = mi.Vector3f(wi.T), mi.Point2f(uv.T)
    si.sh_frame = mi.Frame3f(mi.Vector3f(1, 0, 0), mi.Vector3f(0, 1, 0), mi.Vector3f(0, 0, 1))
    si.dp_du, si.dp_dv = mi.Vector3f(1, 0, 0), mi.Vector3f(0, 1, 0)
    si.p, si.t = mi.Point3f(3.0, 0.0, 0.0), mi.Float(1.0)  # not from the camera below
    w = mi.Vector3f(wo.T)
    ctx = mi.BSDFContext()
    out = {"queries": n, "patch_sizes": list(sizes), "material": a.material}
    plugins, cpu = {}, {}
    for way, rt in ways.items():
        key = sbm.add_material(rt, f"bench-{way}")
        plugins[way] = mi.load_dict({"type": "sparsebtf", "key": key, "lod": "off"})
        # every lookup at a later vertex at fraction 1: the full τ, counted
        count = mi.load_dict({"type": "sparsebtf", "key": key, "lod_camera": "0,0,100",
                              "lod_later": 1.0, "lod_stats": True})  # fmt: skip
        dr.eval(count.eval(ctx, si, w))
        cpu[way] = []
        out[way] = {"coefficients_per_lookup": round(sum(count.lod_stats()["later"]["tau"]), 2),
                    "nodes": (rt.coded.tree.counts() if way == "adaptive"
                              else rt.meta["n_points"])}  # fmt: skip
    for r in range(a.repeat + 1):  # interleaved rounds: both ways see the same machine load
        for way, bsdf in plugins.items():
            t = time.process_time()
            dr.eval(bsdf.eval(ctx, si, w))
            dr.sync_thread()
            if r:  # the first call compiles the kernels
                cpu[way].append(time.process_time() - t)
    for way in ways:
        best = min(cpu[way]) / n
        out[way]["cpu_ns_per_lookup"] = round(best * 1e9, 1)
        out[way]["cpu_ns_per_coefficient"] = round(
            best * 1e9 / out[way]["coefficients_per_lookup"], 2)
    print(json.dumps(out))


if __name__ == "__main__":
    main()

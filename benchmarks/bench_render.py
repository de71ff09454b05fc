"""Mitsuba 3 render time of a coded material (``sparsebtf`` plugin, Dr.Jit LLVM backend).

A coded BTF at full UBO2014 angular resolution (151 lights × 151 views, 10×10 patches,
``--texels`` square texture) with K = 8 random orthonormal dictionaries per channel and
τ = (885, 64, 64) random coefficients sorted by magnitude (as the encoder stores them): the
cost of a lookup depends on τ, K and the angular size, not on the values. Scene: the built-in
sphere on a floor (both with the material), procedural sky, path tracer with max depth 4,
256×256 pixels, 16 spp, linear (2-NN, the release's) angular interpolation in coefficient
space (Eq. 6). Measured in one run:

* the render time at τ = (885, 64, 64) and at a quarter of it, (221, 16, 16), each the best of
  ``--repeat`` renders after a first one that also traces and compiles the kernels;
* their ratio, and the time of the first render (Dr.Jit tracing + LLVM code generation);
* for scale: the same scene with the uncompressed reference plugin (``sparsebtf_dense``) on a
  20×20-texel dense table (109 MB) with the same interpolation.

    python benchmarks/bench_render.py [--size 256] [--spp 16] [--json]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from _common import TAU, machine, report, synthetic_coded
from sparsebtf.data.btf import ArrayBTF
from sparsebtf.data.directions import ubo2014


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", type=int, default=256, help="image side (default 256)")
    ap.add_argument("--spp", type=int, default=16, help="samples per pixel (default 16)")
    ap.add_argument("--texels", type=int, default=40, help="texture side (default 40)")
    ap.add_argument("--repeat", type=int, default=2, help="timed renders per setting")
    ap.add_argument("--interpolation", default="linear")
    ap.add_argument("--no-dense", action="store_true", help="skip the dense reference")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()

    import sparsebtf.mitsuba as sbm
    from sparsebtf.rendering.render import render_material
    from sparsebtf.runtime import RuntimeBTF

    t0 = time.perf_counter()
    coded = synthetic_coded(args.texels)
    full = RuntimeBTF(coded)
    quarter_tau = {ch: t // 4 for ch, t in TAU.items()}
    quarter = full.with_tau(quarter_tau)
    build_s = time.perf_counter() - t0
    keys = {"full": sbm.add_material(full, "bench-full"),
            "quarter": sbm.add_material(quarter, "bench-quarter")}  # fmt: skip
    opts = {"scene": "sphere", "size": (args.size, args.size), "spp": args.spp, "seed": 0}
    bsdf = {"type": "sparsebtf", "interpolation": args.interpolation, "uv_scale": 2.0}

    def timed(plugin: dict) -> tuple[float, list[float], float]:
        first = render_material(plugin, **opts)
        times = [render_material(plugin, **opts)["seconds"] for _ in range(args.repeat)]
        return first["seconds"], times, float(first.image.mean())

    first_full, t_full, mean_full = timed({**bsdf, "key": keys["full"]})
    first_q, t_q, mean_q = timed({**bsdf, "key": keys["quarter"]})
    data = {
        "machine": machine(),
        "variant": sbm.variant,
        "llvm": sbm.variant_message,
        "image": f"{args.size}x{args.size}",
        "spp": args.spp,
        "interpolation": args.interpolation,
        "texels": args.texels,
        "tau": TAU,
        "quarter_tau": quarter_tau,
        "material_build_seconds": build_s,
        "seconds": {
            "full_tau_first_render": first_full,
            "full_tau": min(t_full),
            "quarter_tau_first_render": first_q,
            "quarter_tau": min(t_q),
        },
        "all_seconds": {"full_tau": t_full, "quarter_tau": t_q},
        "mean_pixel": {"full_tau": mean_full, "quarter_tau": mean_q},
    }
    data["ratios"] = {"full_over_quarter": min(t_full) / min(t_q)}
    if not args.no_dense:
        rng = np.random.default_rng(1)
        d = ubo2014()
        table = rng.uniform(0.05, 0.6, (20, 20, 151, 151, 3)).astype(np.float32)
        key = sbm.add_material(ArrayBTF(table, d, d, name="dense20"), "bench-dense")
        first_d, t_d, _ = timed({**bsdf, "type": "sparsebtf_dense", "key": key})
        data["seconds"]["dense_20x20_first_render"] = first_d
        data["seconds"]["dense_20x20"] = min(t_d)
        data["all_seconds"]["dense_20x20"] = t_d
        data["ratios"]["full_over_dense"] = min(t_full) / min(t_d)
        data["ratios"]["quarter_over_dense"] = min(t_q) / min(t_d)
    rows = [(f"seconds {k}", f"{v:.2f}") for k, v in data["seconds"].items()]
    rows += [(f"ratio {k}", f"{v:.2f}") for k, v in data["ratios"].items()]
    rows.insert(0, ("variant", f"{data['variant']} ({data['llvm']})"))
    report(rows, data, args.json)


if __name__ == "__main__":
    main()

"""``sparsebtf capture``: render a BTF of a material sample (built-in or a Mitsuba scene) with
Mitsuba 3, view by view into our dense file (``--resume`` continues an interrupted capture)."""

from __future__ import annotations

import argparse
from typing import Any

from ._args import (
    add_cluster_options,
    check_output_file,
    cluster_options,
    integer,
    output_format,
    parse_crop,
)
from ._output import Written

__all__ = ["register"]


def run(args: argparse.Namespace) -> int:
    from ..data.capture import capture, capture_spec
    from ..data.capture.writer import check_scene
    from ..data.dense_file import dense_file_bytes

    output_format(args.output, "dense")  # capture writes our dense file
    crop = parse_crop(args.crop)
    spec = capture_spec(args.scene, args.size, args.directions, spp=args.spp, seed=args.seed,
                        max_depth=args.max_depth, crop=crop, backend=args.backend,
                        noise_seed=args.noise_seed)  # fmt: skip
    check_output_file(args.output, [args.scene], kind="dense")
    check_scene(spec)  # a bad scene or backend is one line before the size is announced
    say = Written(args.json)
    h, w, nl, nv, _ = spec.shape
    shape = f"{h}x{w} texels, {nl} lights x {nv} views"
    say.announce(args.output, dense_file_bytes(spec.shape, args.dtype),
                 f"{shape}, {args.dtype}, {args.spp} spp")  # fmt: skip
    capture(args.scene, args.output, args.size, args.directions, spp=args.spp, seed=args.seed,
            max_depth=args.max_depth, crop=crop, noise_seed=args.noise_seed, dtype=args.dtype,
            resume=args.resume,
            backend=args.backend, progress=None, **cluster_options(args))  # fmt: skip
    say.wrote(args.output, f"{shape} ({spec.directions_name})", kind="dense",
              shape=list(spec.shape), dtype=args.dtype)  # fmt: skip
    say.finish()
    return 0


def register(sub: Any) -> None:
    from ..data.capture import SAMPLES

    s = sub.add_parser(
        "capture",
        help="render a BTF of a material sample with Mitsuba 3 (virtual gonioreflectometer)",
        description="For every (light, view) pair a distant directional light and a rectified "
        "orthographic view (texel (x, y) fixed across views, as in UBO2014's rectified images); "
        "the sample repeats with period 2, so edges see their neighbours. Values: a Lambertian "
        "plane of albedo rho gives rho*cos(theta_light) (docs/format.md).",
    )
    names = "; ".join(f"{k} ({v.description})" for k, v in SAMPLES.items())
    s.add_argument("scene", metavar="SCENE",
                   help=f"a built-in sample: {names}; or a Mitsuba scene file (.xml, or .py "
                   "defining scene(seed) -> dict) describing one period of the sample on the "
                   "tile x, y in [-1, 1] around z = 0")  # fmt: skip
    s.add_argument("-o", "--output", required=True, help="dense BTF file to write (.h5)")
    s.add_argument("--size", type=int, default=64,
                   help="texels per side over the tile (default 64)")  # fmt: skip
    s.add_argument("--crop", metavar="R0:R1,C0:C1",
                   help="render only this window of the size x size texels (a tile of a "
                   "larger sample)")  # fmt: skip
    s.add_argument("--directions", default="ubo2014",
                   help="light and view directions: ubo2014 (151), ubo2003 (81), tiny7/13/19 "
                   "(default ubo2014)")  # fmt: skip
    s.add_argument("--spp", type=int, default=16,
                   help="camera paths per texel, jittered over its square (default 16)")
    s.add_argument("--max-depth", type=int, default=3,
                   help="path segments as Mitsuba counts them: 2 direct light only, 3 (default) "
                   "one bounce of inter-reflection")  # fmt: skip
    s.add_argument("--seed", type=int, default=0,
                   help="random seed of the sample's geometry and texture and of the Monte "
                   "Carlo noise (default 0)")  # fmt: skip
    s.add_argument("--noise-seed", type=int, default=None,
                   help="random seed of the Monte Carlo noise alone (default: --seed): the same "
                   "sample with independent noise, whose difference from a capture measures "
                   "that capture's noise")  # fmt: skip
    s.add_argument("--dtype", choices=["float32", "float16"], default="float32",
                   help="value type of the dense file (default float32)")
    s.add_argument("--backend", choices=["auto", "llvm", "cuda", "scalar"], default="auto",
                   help="Mitsuba variant: auto (LLVM, else scalar), cuda (a GPU if one works)")
    s.add_argument("--resume", action="store_true",
                   help="continue an interrupted capture from OUT.partial")
    add_cluster_options(s)
    s.add_argument("--json", action="store_true", help="print what was written as JSON")
    s.set_defaults(func=run, checks={
        "size": integer(1, 8192, unit="texels per side"),
        "spp": integer(1, 1 << 16, unit="paths per texel"),
        "max_depth": integer(2, 64, unit="path segments"),
        "seed": integer(0, 2**32 - 1),
        "noise_seed": integer(0, 2**32 - 1),
    })  # fmt: skip

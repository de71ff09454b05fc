"""``sparsebtf render``: path-trace a coded material with Mitsuba 3 (optionally vs. its reference).

::

    sparsebtf render stone.coded.h5 -o stone.png --scene sphere --spp 64 --image-size 512 \
        --uv-scale 2
    sparsebtf render stone.coded.h5 -o cmp.png --reference stone.h5 --json   # Figures 7/8 style

With ``--reference`` the same scene (same sampler seed) is rendered with the uncompressed BTF
(``sparsebtf_dense`` plugin) and ``-o`` receives [coded | reference | error] with MSE / PSNR /
SSIM; ``--json`` prints the numbers. Heavy modules (Mitsuba, Dr.Jit) load inside the command.
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path
from typing import Any

from ..errors import SparseBTFError
from ..runtime.angular import SCHEMES
from ._args import add_deprecated_alias, check_output_file, check_tau, integer, number

__all__ = ["cmd_render", "register"]


def _parse_size(text: str) -> tuple[int, int]:
    try:
        if "x" in text.lower():
            w, h = (int(v) for v in text.lower().split("x"))
        else:
            w = h = int(text)
    except ValueError:
        raise SparseBTFError(
            f"--image-size must look like 256 or 320x240 (pixels), got {text!r}"
        ) from None
    if not (1 <= w <= 16384 and 1 <= h <= 16384):
        raise SparseBTFError(f"--image-size {text!r}: width and height must be in [1, 16384] "
                             "pixels")  # fmt: skip
    return w, h


def _refuse_slow_scalar(args: argparse.Namespace, size: tuple[int, int]) -> None:
    """Without a usable libLLVM, refuse (before minutes of waiting) a scalar render estimated
    over a minute, naming the one install command; ``--backend scalar`` runs it anyway."""
    if args.backend == "scalar":
        return
    from ..llvm import choose_variant
    from ..rendering.render import scalar_seconds

    variant, _ = choose_variant(args.backend)
    seconds = scalar_seconds(size, args.spp, 2 if args.reference else 1)
    if variant == "scalar_rgb" and seconds > 60:
        raise SparseBTFError(
            f"no usable libLLVM (>= 17) for Mitsuba's fast CPU backend; install one with "
            f"'apt-get install libllvm19' (Debian/Ubuntu) or set DRJIT_LIBLLVM_PATH. Without it "
            f"this render would take about {seconds / 60:.0f} min in the scalar fallback: "
            f"lower --image-size/--spp (e.g. --image-size 32 --spp 4) or pass --backend scalar "
            "to wait"
        )


def cmd_render(args: argparse.Namespace) -> int:
    from ..rendering.mitsuba import add_material, dense_table
    from ..rendering.mitsuba.materials import runtime_for
    from ..rendering.render import (
        compare_renders,
        render_material,
        save_png,
        save_side_by_side,
    )

    size = _parse_size(args.image_size)
    check_tau(args.tau)
    if not Path(args.coded).exists():
        raise SparseBTFError(f"{args.coded}: no such file")
    inputs = [args.coded, args.model, args.reference, args.envmap]
    check_output_file(args.output, inputs, kind="png")
    check_output_file(args.save_raw, [*inputs, args.output], flag="--save-raw", kind="npz")
    _refuse_slow_scalar(args, size)
    common: dict[str, Any] = {
        "uv_scale": float(args.uv_scale),
        "interpolation": args.interpolation,
        "two_sided": not args.one_sided,
        "sampling": args.sampling,
    }
    if args.interpolation == "gaussian":
        common["k"] = int(args.k)
        common["beta"] = float(args.beta)
    coded_bsdf: dict[str, Any] = {
        "type": "sparsebtf",
        "filename": str(args.coded),
        "domain": args.domain,
        "lod": args.lod,
        **common,
    }
    if args.model:
        coded_bsdf["model"] = str(args.model)
    if args.tau:
        coded_bsdf["tau"] = str(args.tau)
    reference = None
    if args.reference:
        from ..open import open_btf
        from ..storage import load_coded_with_model

        ref_btf = open_btf(args.reference)
        coded = load_coded_with_model(args.coded, args.model, adaptive=True)
        if (ref_btf.height, ref_btf.width) != (coded.height, coded.width) or not (
            ref_btf.lights.equals(coded.lights) and ref_btf.views.equals(coded.views)
        ):
            raise SparseBTFError(
                f"reference {args.reference} ({ref_btf.height}x{ref_btf.width}, "
                f"{len(ref_btf.lights)}x{len(ref_btf.views)} directions) does not match "
                f"{args.coded} ({coded.height}x{coded.width}, {len(coded.lights)}x"
                f"{len(coded.views)}); crop or choose the reference the codes were made from"
            )
        need = ref_btf.n_values * 4
        if need > args.max_gib * 2**30:
            dense_table(ref_btf, max_gib=args.max_gib)  # raises the explanatory error
        key = add_material(ref_btf, f"cli-reference:{args.reference}")
        reference = {"type": "sparsebtf_dense", "key": key, "max_gib": float(args.max_gib),
                     **common}  # fmt: skip
        if args.sampling == "btf":  # sample as the coded render does: correlated noise
            reference["sampling_key"] = add_material(runtime_for(coded, args.tau),
                                                     f"cli-sampling:{args.coded}")  # fmt: skip
    opts = {
        "scene": args.scene,
        "size": size,
        "spp": args.spp,
        "envmap": args.envmap,
        "max_depth": args.max_depth,
        "seed": args.seed,
        "floor": args.floor,
        "backend": args.backend,
        "mode": args.mode,
    }
    res = render_material(coded_bsdf, **opts)
    out: dict[str, Any] = {
        "output": str(args.output),
        "variant": res["variant"],
        "mode": res["mode"],
        "scene": args.scene,
        "size": list(size),
        "spp": args.spp,
        "tau": args.tau,
        "lod": args.lod,
        "interpolation": args.interpolation,
        "domain": args.domain,
        "sampling": args.sampling,
        "uv_scale": args.uv_scale,
        "seconds": res["seconds"],
        "setup_seconds": res["setup_seconds"],
        "plugin": res["plugin"],
        "mean": float(res.image.mean()),
    }
    ref = None
    if reference is not None:
        ref = render_material(reference, **opts)
        metrics = compare_renders(res.image, ref.image, exposure=args.exposure)
        out.update(
            {
                "reference": str(args.reference),
                "reference_seconds": ref["seconds"],
                "reference_setup_seconds": ref["setup_seconds"],
                **metrics,
            }
        )
        label = f"SparseBTF ({args.tau or 'all coefficients'})"
        save_side_by_side(args.output, res.image, ref.image, metrics, (label, "reference"))
    else:
        save_png(args.output, res.image, args.exposure)
    if args.save_raw:
        import numpy as np

        from .._atomic import atomic_output

        with atomic_output(args.save_raw) as tmp, open(tmp, "wb") as fh:
            arrays = {"render": res.image}
            if ref is not None:
                arrays["reference"] = ref.image
            np.savez_compressed(fh, **arrays)
        out["raw"] = str(args.save_raw)
    if args.json:
        clean = {k: None if isinstance(v, float) and not math.isfinite(v) else v
                 for k, v in out.items()}  # fmt: skip
        print(json.dumps(clean, indent=2, sort_keys=True, default=str))
    else:
        line = f"wrote {args.output}: {res['variant']}, {size[0]}x{size[1]}, {args.spp} spp, " \
               f"{res['seconds']:.2f} s"
        if reference is not None:
            line += (f"; vs reference (linear RGB): MSE {out['mse']:.4g}, PSNR "
                     f"{out['psnr']:.2f} dB (peak {out['peak']:.4g}), "
                     f"SSIM {out['ssim']:.4f} (reference render {out['reference_seconds']:.2f} s)")
        print(line)
    return 0


def register(sub: Any) -> None:
    """Add the ``render`` subcommand to the ``sparsebtf`` parser's subparsers."""
    s = sub.add_parser(
        "render",
        help="path-trace a coded material with Mitsuba 3 (optionally beside its reference)",
        description="Render a coded BTF with the Mitsuba 3 'sparsebtf' plugin (llvm_ad_rgb; "
        "scalar_rgb when no usable libLLVM is found) in a built-in scene lit by an environment "
        "map. With --reference, also render the uncompressed BTF and write a side-by-side PNG "
        "with MSE/PSNR/SSIM (paper Figures 7/8).",
    )
    s.add_argument("coded", help="coded file (.h5 from 'sparsebtf encode', with fixed or adaptive "
                   "patch sizes, or 'import-release')")
    s.add_argument("-o", "--output", required=True, help="PNG to write")
    s.add_argument("-m", "--model", help="model file or bundled model name (default: the one "
                   "the coded file names)")
    s.add_argument("--scene", choices=["sphere", "cloth"], default="sphere",
                   help="sphere on a plane (default) or a procedurally draped cloth")
    s.add_argument("--floor", choices=["material", "diffuse"], default=None,
                   help="floor material (default: the BTF for sphere, grey for cloth)")
    s.add_argument("--envmap", default=None,
                   help="environment map: .exr/.hdr lat-long file (default: a procedural sky)")
    s.add_argument("--spp", type=int, default=16, help="samples per pixel (default 16)")
    s.add_argument("--image-size", default="256", metavar="PIXELS",
                   help="image size in pixels, 256 or WxH (default 256)")
    add_deprecated_alias(s, "--size", "--image-size",
                         "in 'render' it meant pixels; 'synth --size' is texels")
    s.add_argument("--uv-scale", type=float, default=1.0,
                   help="texture tiling: uv -> uv*scale (default 1)")
    s.add_argument("--tau", default=None,
                   help="level of detail: 885,64,64, one integer, or a fraction such as 0.25 "
                   "(default: every stored coefficient)")
    s.add_argument("--lod", choices=["auto", "off"], default="auto",
                   help="level of detail: auto (tau per lookup from the path depth and the "
                   "pixel footprint, capped by --tau; default) or off (every lookup at --tau)")
    s.add_argument("--interpolation", choices=SCHEMES,
                   default="linear", help="angular interpolation (default linear, the release's)")
    s.add_argument("--domain", choices=["standardized", "log"], default="standardized",
                   help="interpolation domain of the coded lookup (default standardized, Eq. 6)")
    s.add_argument("--k", type=int, default=4, help="gaussian: neighbours (default 4)")
    s.add_argument("--beta", type=float, default=20.0, help="gaussian: sharpness (default 20)")
    s.add_argument("--one-sided", action="store_true", help="black back faces (default two-sided)")
    s.add_argument("--sampling", choices=["btf", "cosine"], default="btf",
                   help="direction sampling: btf (from the material's angular response, "
                   "default) or cosine")
    s.add_argument("--reference", metavar="BTF",
                   help="also render this uncompressed BTF (.h5, .btf, .zip, synth:...) and "
                   "compare")
    s.add_argument("--max-gib", type=float, default=2.0,
                   help="refuse references whose float32 table exceeds this (default 2 GiB)")
    s.add_argument("--max-depth", type=int, default=4, help="path length (default 4)")
    s.add_argument("--seed", type=int, default=0, help="sampler seed (default 0)")
    s.add_argument("--exposure", type=float, default=None,
                   help="display exposure (default: 99th luminance percentile -> 0.9)")
    s.add_argument("--backend", choices=["auto", "llvm", "cuda", "scalar"], default="auto",
                   help="Mitsuba variant: auto (llvm_ad_rgb, else scalar_rgb), cuda, llvm, scalar")
    s.add_argument("--mode", choices=["auto", "symbolic", "evaluated"], default="auto",
                   help="Dr.Jit's mode: evaluated hands the coded lookups to the runtime's "
                        "compiled kernel (auto: evaluated on llvm with numba, else symbolic)")
    s.add_argument("--save-raw", metavar="NPZ", help="also save the linear float renders (.npz)")
    s.add_argument("--json", action="store_true", help="print the numbers as JSON")
    s.set_defaults(func=cmd_render, checks={
        "spp": integer(1, 2**20, unit="samples per pixel"),
        "uv_scale": number(0, 1e6, lo_open=True),
        "k": integer(1, 64, unit="neighbours"),
        "beta": number(0, 1e6, lo_open=True),
        "max_gib": number(0, lo_open=True, unit="GiB"),
        "max_depth": integer(1, 1024, unit="bounces"),
        "seed": integer(0, 2**31 - 1),
        "exposure": number(0, lo_open=True),
    })  # fmt: skip

"""The ``sparsebtf`` command: a thin layer over the Python API.

Every command has ``--help``; long work shows a progress bar with ETA on a terminal
(``SPARSEBTF_PROGRESS=1`` forces it, ``=0`` silences it); ``--json`` prints one JSON object.
Errors in the user's input print one line ``sparsebtf: error: …`` and exit with status 2.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import SparseBTFError

__all__ = ["main"]


def _print_json(obj: Any) -> None:
    print(json.dumps(obj, indent=2, sort_keys=True, default=_json_default))


def _json_default(o: Any) -> Any:
    if isinstance(o, np.integer):
        return int(o)
    if isinstance(o, np.floating):
        return float(o)
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


def _table(rows: list[tuple[str, Any]]) -> str:
    width = max(len(k) for k, _ in rows)
    return "\n".join(f"{k:<{width}}  {v}" for k, v in rows)


def _parse_crop(text: str | None) -> tuple[slice, slice] | None:
    if not text:
        return None
    try:
        r, c = text.split(",")
        r0, r1 = (int(x) for x in r.split(":"))
        c0, c1 = (int(x) for x in c.split(":"))
    except ValueError:
        raise SparseBTFError(f"--crop must look like R0:R1,C0:C1, got {text!r}") from None
    return slice(r0, r1), slice(c0, c1)


def _open(source: str, model: str | None = None, crop: str | None = None):
    from ..data.io import open_btf

    btf = open_btf(source, model)
    window = _parse_crop(crop)
    if window is not None:
        from ..data.crop import CroppedBTF

        btf = CroppedBTF(btf, *window)
    return btf


# -- commands ---------------------------------------------------------------------------------
def cmd_synth(args: argparse.Namespace) -> int:
    from ..data.dense_file import write_dense
    from ..data.synth import contact_sheet, synthesize

    if args.source:
        # Preview (or convert) any BTF the user has: .btf, our .h5, synth:...
        btf = _open(args.source)
    elif args.material:
        btf = synthesize(args.material, args.size, args.directions, args.seed)
    else:
        raise SparseBTFError("give --class CLASS to synthesise, or --from BTF to preview a BTF")
    if not args.output and not args.preview:
        raise SparseBTFError("nothing to do: give -o OUT.h5 and/or --preview OUT.png")
    if args.output:
        write_dense(args.output, btf, dtype=args.dtype, progress=None)
        print(
            f"wrote {args.output}: {btf.shape[0]}x{btf.shape[1]} texels, "
            f"{len(btf.lights)} lights x {len(btf.views)} views ({btf.lights.name})"
        )
        if args.preview:
            btf = _open(args.output)
    if args.preview:
        contact_sheet(btf, args.preview)
        print(f"wrote {args.preview}")
    return 0


def cmd_info(args: argparse.Namespace) -> int:
    from ..info import describe

    info = describe(args.file, model_path=args.model, scan=not args.no_scan)
    if args.json:
        _print_json(info)
    else:
        print(_table([(k, v) for k, v in info.items() if not isinstance(v, dict | list)]))
        for k, v in info.items():
            if isinstance(v, dict | list):
                print(f"{k}: {json.dumps(v, default=_json_default)}")
    return 0


def cmd_train(args: argparse.Namespace) -> int:
    from ..codec import train
    from ..storage import save_model

    btfs = [_open(s, crop=args.crop) for s in args.btfs]
    model = train(
        btfs,
        n_dictionaries=args.dicts,
        tau_train=args.tau_train,
        patch=args.patch,
        sample=args.sample,
        max_iter=args.iters,
        tol=args.tol,
        std_mode=args.std_mode,
        colour_mode=args.colour_mode,
        batch_size=args.batch,
        seed=args.seed,
        checkpoint_dir=args.checkpoint_dir,
    )
    save_model(model, args.output)
    summary = {
        "model": args.output,
        "content_hash": model.content_hash,
        "channels": list(model.channels),
        "mode_sizes": list(model.mode_sizes),
        "training": model.training,
    }
    if args.json:
        _print_json(summary)
    else:
        for ch, t in model.training.items():
            print(
                f"{ch}: {t['n_points']} points, {t['n_iter']} iterations, objective "
                f"{t['objective'][0]:.4g} -> {t['objective'][-1]:.4g}, membership "
                f"{t['membership_counts']}, {t['seconds']:.1f} s"
            )
        print(f"wrote {args.output} (model {model.content_hash[:12]})")
    return 0


def cmd_encode(args: argparse.Namespace) -> int:
    from ..codec import encode
    from ..storage import load_model, save_coded, storage_report

    model = load_model(args.model)
    btf = _open(args.btf, crop=args.crop)
    if args.target_ratio is not None or args.target_bytes is not None:
        from ..codec import encode_to_size

        coded = encode_to_size(
            btf, model, target_bytes=args.target_bytes, target_ratio=args.target_ratio,
            per_material=args.per_material, std_mode=args.std_mode, batch_size=args.batch,
        )
    else:
        coded = encode(
            btf,
            model,
            tau=args.tau or "885,64,64",
            eps=args.eps,
            std_mode=args.std_mode,
            batch_size=args.batch,
            allow_below_training=args.allow_below_training,
        )
    coded.params["model_file"] = str(Path(args.model).resolve())
    save_coded(coded, args.output)
    report = storage_report(coded, model, args.output)
    if args.json:
        _print_json(report)
    else:
        print(
            f"wrote {args.output}: nnz {coded.nnz()}, {report['bytes_total'] / 2**20:.3f} MiB "
            f"(paper accounting), ratio {report['compression_ratio']:.1f}, file "
            f"{report['file_bytes'] / 2**20:.3f} MiB"
        )
    return 0


def cmd_decode(args: argparse.Namespace) -> int:
    from ..codec import coded_btf_view
    from ..data.dense_file import write_dense
    from ..storage import load_coded_with_model

    coded = load_coded_with_model(args.coded, args.model)
    view = coded_btf_view(coded)
    if args.images:
        from ..figures import save_angular_images

        pairs = _parse_pairs(args.images)
        outdir = Path(args.png or ".")
        for path in save_angular_images(view, pairs, outdir):
            print(f"wrote {path}")
    if args.output:
        write_dense(args.output, view, progress=None, by="regions")
        print(f"wrote {args.output}")
    if not args.output and not args.images:
        raise SparseBTFError("nothing to do: give -o OUT.h5 and/or --images L:V,...")
    return 0


def _parse_pairs(text: str) -> list[tuple[int, int]]:
    try:
        return [(int(a), int(b)) for a, b in (item.split(":") for item in text.split(","))]
    except ValueError:
        raise SparseBTFError(f"--images must look like L:V,L:V (indices), got {text!r}") from None


def cmd_eval(args: argparse.Namespace) -> int:
    from ..codec import coded_btf_view
    from ..metrics import compare
    from ..storage import load_coded_with_model, storage_report

    coded = load_coded_with_model(args.coded, args.model)
    reference = _open(args.reference, crop=args.crop)
    metrics = compare(
        reference, coded_btf_view(coded), stats=coded.stats, ssim_images=args.ssim_images
    )
    metrics["mse_std_codes"] = float(
        np.mean([coded.codes[ch].errors.mean() for ch in coded.channels])
    )
    report = storage_report(coded, coded.model, args.coded)
    out = {
        **metrics,
        **{
            k: report[k]
            for k in (
                "nnz",
                "bytes_coefficients",
                "bytes_dictionaries",
                "bytes_stats",
                "bytes_total",
                "bytes_raw",
                "compression_ratio",
                "file_bytes",
            )
        },
    }
    if args.json:
        _print_json(out)
    else:
        print(_table([(k, v) for k, v in out.items()]))
    return 0


def cmd_convert(args: argparse.Namespace) -> int:
    from ..data.dense_file import write_dense

    btf = _open(args.input, crop=args.crop)
    write_dense(args.output, btf, dtype=args.dtype, progress=None)
    print(f"wrote {args.output}: {btf.height}x{btf.width} texels, {len(btf.lights)} lights x "
          f"{len(btf.views)} views")
    return 0


def cmd_import_release(args: argparse.Namespace) -> int:
    from ..formats.release import import_release
    from ..storage import save_coded, save_model

    model, coded, notes = import_release(args.folder, prefer=args.prefer)
    save_model(model, args.output)
    out_dir = Path(args.coded_dir) if args.coded_dir else Path(args.output).resolve().parent
    written = {}
    for name, c in coded.items():
        c.params["model_file"] = str(Path(args.output).resolve())
        path = out_dir / f"{name}.coded.h5"
        save_coded(c, path)
        written[name] = str(path)
    if args.json:
        _print_json({"model": args.output, "content_hash": model.content_hash,
                     "coded": written, "notes": notes})
    else:
        for n in notes:
            print(n)
        print(f"wrote {args.output} (model {model.content_hash[:12]})")
        for path in written.values():
            print(f"wrote {path}")
    return 0


def cmd_lookup(args: argparse.Namespace) -> int:
    from ..lookup import lookup

    try:
        r, c = (int(v) for v in args.texel.split(","))
    except ValueError:
        raise SparseBTFError(f"--texel must look like R,C, got {args.texel!r}") from None
    out = lookup(args.file, r, c, args.light, args.view, model_path=args.model)
    if args.json:
        _print_json(out)
    else:
        print(_table([(k, json.dumps(v, default=_json_default)) for k, v in out.items()]))
    return 0


def cmd_demo(args: argparse.Namespace) -> int:
    from ..demo import run_demo

    run_demo(Path(args.out), quick=args.quick, seed=args.seed, as_json=args.json)
    return 0


# -- parser -------------------------------------------------------------------------------------
def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="sparsebtf",
        description="SparseBTF: learn, encode, store and decode Bidirectional Texture Functions "
        "with sparse coefficients on an ensemble of orthonormal 4D dictionaries (EGSR 2023).",
    )
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")

    s = sub.add_parser("synth", help="render a synthetic material (dense BTF file, preview PNG)")
    s.add_argument(
        "--class",
        dest="material",
        help="carpet, fabric, felt, leather, stone, wallpaper or wood",
    )
    s.add_argument(
        "--from",
        dest="source",
        metavar="BTF",
        help="instead of synthesising, preview/convert this BTF (.btf, .h5, synth:...)",
    )
    s.add_argument("--size", type=int, default=64, help="texels per side (default 64)")
    s.add_argument(
        "--directions",
        default="ubo2014",
        help="ubo2014 (151), ubo2003 (81), tiny7/13/19 (default ubo2014)",
    )
    s.add_argument("--seed", type=int, default=0)
    s.add_argument("--dtype", choices=["float32", "float16"], default="float32")
    s.add_argument("-o", "--output", help="dense BTF file to write (.h5)")
    s.add_argument("--preview", help="PNG contact sheet of angular images to write")
    s.set_defaults(func=cmd_synth)

    s = sub.add_parser("info", help="describe a BTF, model or coded file")
    s.add_argument("file", help="a .h5 file of ours, or synth:CLASS[:SIZE[:SEED]]")
    s.add_argument("-m", "--model", help="model file (for a coded file's storage figures)")
    s.add_argument("--no-scan", action="store_true", help="skip the value-range scan")
    s.add_argument("--json", action="store_true", help="print one JSON object")
    s.set_defaults(func=cmd_info)

    s = sub.add_parser("train", help="learn a model (three dictionary ensembles) from BTFs")
    s.add_argument("btfs", nargs="+", metavar="BTF",
                   help="training BTFs: dense .h5 files or synth:CLASS[:SIZE[:SEED]]")
    s.add_argument("-o", "--output", required=True, help="model file to write (.h5)")
    s.add_argument("--dicts", type=int, default=8, help="dictionaries per ensemble K (default 8)")
    s.add_argument(
        "--tau-train",
        default="256,32,32",
        help="training sparsity per channel Y,U,V (default 256,32,32)",
    )
    s.add_argument("--patch", type=int, default=10, help="spatial patch size p (default 10)")
    s.add_argument(
        "--sample",
        type=float,
        default=0.1,
        help="fraction of each BTF's data points used (default 0.1)",
    )
    s.add_argument("--iters", type=int, default=10, help="maximum iterations (default 10)")
    s.add_argument(
        "--tol",
        type=float,
        default=1e-4,
        help="stop below this relative objective decrease (default 1e-4)",
    )
    s.add_argument(
        "--std-mode",
        choices=["shared", "per_channel"],
        default="shared",
        help="standardisation: the release's shared mean/std, or per channel",
    )
    s.add_argument(
        "--colour-mode",
        action="store_true",
        help="one 5D ensemble with colour as a mode (paper Table 6)",
    )
    s.add_argument("--batch", type=int, default=4, help="data points per batch (memory bound)")
    s.add_argument("--seed", type=int, default=0)
    s.add_argument("--crop", help="use only rows R0:R1 and columns C0:C1 of every BTF")
    s.add_argument("--checkpoint-dir", help="save after each iteration and resume from here")
    s.add_argument("--json", action="store_true")
    s.set_defaults(func=cmd_train)

    s = sub.add_parser("encode", help="code one BTF on a model")
    s.add_argument("btf", metavar="BTF", help="the BTF to code (.h5 or synth:...)")
    s.add_argument("-m", "--model", required=True, help="model file from 'sparsebtf train'")
    s.add_argument("-o", "--output", required=True, help="coded file to write (.h5)")
    size = s.add_mutually_exclusive_group()
    size.add_argument(
        "--tau", default=None, help="sparsity cap per channel (default 885,64,64)"
    )
    size.add_argument("--target-ratio", type=float, default=None,
                      help="rate control: reach this compression ratio (paper accounting)")
    size.add_argument("--target-bytes", type=int, default=None,
                      help="rate control: reach this size in bytes (paper accounting)")
    s.add_argument("--per-material", action="store_true",
                   help="targets exclude the shared dictionaries (per-material ratio/bytes)")
    s.add_argument("--eps", type=float, default=1e-5, help="residual MSE threshold (default 1e-5)")
    s.add_argument(
        "--std-mode", choices=["shared", "per_channel"], default=None, help="default: the model's"
    )
    s.add_argument("--batch", type=int, default=4)
    s.add_argument("--crop", help="encode only rows R0:R1 and columns C0:C1")
    s.add_argument(
        "--allow-below-training", action="store_true", help="accept tau below the training sparsity"
    )
    s.add_argument("--json", action="store_true")
    s.set_defaults(func=cmd_encode)

    s = sub.add_parser("decode", help="reconstruct a coded BTF (dense file and/or PNG images)")
    s.add_argument("coded", help="coded file from 'sparsebtf encode'")
    s.add_argument("-m", "--model", help="model file (default: the one named in the coded file)")
    s.add_argument("-o", "--output", help="dense BTF file to write (.h5)")
    s.add_argument("--images", help="angular images to write as PNG, e.g. 0:0,10:42 (light:view)")
    s.add_argument("--png", help="folder for --images (default .)")
    s.set_defaults(func=cmd_decode)

    s = sub.add_parser("eval", help="quality and storage of a coded BTF against its reference")
    s.add_argument("coded", help="coded file from 'sparsebtf encode'")
    s.add_argument("--reference", required=True, metavar="BTF", help="the original BTF")
    s.add_argument("-m", "--model", help="model file (default: the one named in the coded file)")
    s.add_argument("--crop", help="crop the reference like the coded BTF was cropped")
    s.add_argument(
        "--ssim-images", type=int, default=16, help="angular images sampled for SSIM (default 16)"
    )
    s.add_argument("--json", action="store_true")
    s.set_defaults(func=cmd_eval)

    s = sub.add_parser("convert", help="any BTF (.btf, .h5, synth:...) to our dense file")
    s.add_argument("input", metavar="IN", help="a .btf, dense/coded .h5, or synth:CLASS[:SIZE]")
    s.add_argument("-o", "--output", required=True, help="dense BTF file to write (.h5)")
    s.add_argument("--crop", help="keep rows R0:R1 and columns C0:C1")
    s.add_argument("--dtype", choices=["float32", "float16"], default="float32")
    s.set_defaults(func=cmd_convert)

    s = sub.add_parser("import-release",
                       help="the authors' released dictionaries/coefficients as our files")
    s.add_argument("folder", help="folder with DictEnsOrth4D{Y,U,V}.bin/.mat, Coeffs_*.bin, "
                   "*_mean_std.bin, bonn_angles.bin")
    s.add_argument("-o", "--output", required=True, help="model file to write (.h5)")
    s.add_argument("--coded-dir", help="folder for <material>.coded.h5 (default: beside -o)")
    s.add_argument("--prefer", choices=["mat", "bin"], default="mat",
                   help="dictionaries from the fp64 .mat (exact, default) or the fp16 .bin")
    s.add_argument("--json", action="store_true")
    s.set_defaults(func=cmd_import_release)

    s = sub.add_parser("lookup", help="one value of a coded or dense BTF, in every domain")
    s.add_argument("file", help="coded or dense .h5 file")
    s.add_argument("--texel", required=True, help="R,C (row, column; the release's convention)")
    s.add_argument("--light", type=int, required=True, help="sampled light index")
    s.add_argument("--view", type=int, required=True, help="sampled view index")
    s.add_argument("-m", "--model", help="model file (default: the one named in the coded file)")
    s.add_argument("--json", action="store_true")
    s.set_defaults(func=cmd_lookup)

    s = sub.add_parser("demo", help="synthesise, train, encode at several tau, report and plot")
    s.add_argument("--out", default="sparsebtf-demo", help="output folder (default sparsebtf-demo)")
    s.add_argument("--quick", action="store_true", help="smaller sizes (about a minute)")
    s.add_argument("--seed", type=int, default=0)
    s.add_argument("--json", action="store_true", help="also print the results as JSON")
    s.set_defaults(func=cmd_demo)

    # Commands defined in their own modules: each has register(sub) adding its subparser.
    from . import bench, blend, render, view

    for module in (blend, render, view, bench):
        module.register(sub)
    return p


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except SparseBTFError as e:
        print(f"sparsebtf: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("sparsebtf: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())

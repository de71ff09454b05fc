"""``sparsebtf import-release``: the authors' released ensembles and coefficients as our files."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from ..errors import SparseBTFError
from ._args import check_output_dir, check_output_file
from ._model import open_model_arg
from ._output import print_json

__all__ = ["register"]


def _size(text: str) -> tuple[int, int]:
    """``HxW`` → (H, W), multiples of the release's 10-texel patches."""
    h, x, w = text.lower().partition("x")
    if not (x and h.isdigit() and w.isdigit() and int(h) > 0 and int(w) > 0
            and int(h) % 10 == 0 and int(w) % 10 == 0):
        raise SparseBTFError(f"--size {text}: expected HxW, positive multiples of 10 (400x400)")
    return int(h), int(w)


def run(args: argparse.Namespace) -> int:
    from ..storage import save_coded, save_model
    from ..storage.release import import_release

    if args.output is None and args.model is None:
        raise SparseBTFError("give -o MODEL.h5 (the model file to write) or -m NAME (code the "
                             "coefficients against a bundled model, e.g. -m release)")
    check_output_file(args.output, kind="model")
    check_output_dir(args.coded_dir, "--coded-dir")
    against = open_model_arg(args.model) if args.model else None
    height, width = _size(args.size)
    # Every input file is read and checked here, before anything is written.
    model, coded, notes = import_release(args.folder, prefer=args.prefer, model=against,
                                         height=height, width=width)
    if not coded and not args.output:
        raise SparseBTFError(
            f"{args.folder}: no Coeffs_BTF_<name>_<eps>_<CH>.bin files, so nothing to write "
            "(-o MODEL.h5 writes the dictionaries alone as a model)"
        )
    out_dir = Path(args.coded_dir or (Path(args.output).resolve().parent if args.output else "."))
    written: dict[str, str] = {}
    done: list[Path] = []  # each file is written whole (temporary + rename); on a failure
    try:  # part way (a full disk) the files of this run are removed: no half-written set
        if args.output:
            save_model(model, args.output)
            done.append(Path(args.output))
            model_path = str(Path(args.output).resolve())
        for name, c in coded.items():
            if args.output:
                c.params["model_file"] = model_path
            path = out_dir / f"{name}.coded.h5"
            save_coded(c, path)
            done.append(path)
            written[name] = str(path)
    except BaseException:
        for path in done:
            path.unlink(missing_ok=True)
        raise
    if args.json:
        print_json({"model": args.output or args.model, "content_hash": model.content_hash,
                    "coded": written, "notes": notes})
    else:
        for n in notes:
            print(n)
        if args.output:
            print(f"wrote {args.output} (model {model.content_hash[:12]})")
        for path in written.values():
            print(f"wrote {path}")
    return 0


def register(sub: Any) -> None:
    s = sub.add_parser("import-release",
                       help="the authors' released dictionaries/coefficients as our files")
    s.add_argument("folder", help="folder with DictEnsOrth4D{Y,U,V}.bin/.mat, Coeffs_*.bin, "
                   "*_mean_std.bin, bonn_angles.bin (the authors' GitHub release)")
    s.add_argument("-o", "--output", help="model file to write (.h5)")
    s.add_argument("-m", "--model",
                   help="code the coefficients against this model instead (a bundled name such "
                   "as 'release', or a file) after checking its dictionaries equal the folder's "
                   "within float32 rounding; no model file is written unless -o is given")
    s.add_argument("--coded-dir",
                   help="folder for <material>.coded.h5 (default: beside -o, else the current "
                   "folder)")
    s.add_argument("--prefer", choices=["mat", "bin"], default="mat",
                   help="dictionaries from the fp64 .mat (exact, default) or the fp16 .bin")
    s.add_argument("--size", default="400x400",
                   help="texels HxW of every material (the files do not say; default 400x400, "
                   "the release's; export-release prints the size to give)")
    s.add_argument("--json", action="store_true", help="print what was written as JSON")
    s.set_defaults(func=run)

"""``sparsebtf import-release``: the authors' released ensembles and coefficients as our files."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from ._args import check_output_dir, check_output_file
from ._output import print_json

__all__ = ["register"]


def run(args: argparse.Namespace) -> int:
    from ..storage import save_coded, save_model
    from ..storage.release import import_release

    check_output_file(args.output)
    check_output_dir(args.coded_dir, "--coded-dir")
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
        print_json({"model": args.output, "content_hash": model.content_hash,
                    "coded": written, "notes": notes})
    else:
        for n in notes:
            print(n)
        print(f"wrote {args.output} (model {model.content_hash[:12]})")
        for path in written.values():
            print(f"wrote {path}")
    return 0


def register(sub: Any) -> None:
    s = sub.add_parser("import-release",
                       help="the authors' released dictionaries/coefficients as our files")
    s.add_argument("folder", help="folder with DictEnsOrth4D{Y,U,V}.bin/.mat, Coeffs_*.bin, "
                   "*_mean_std.bin, bonn_angles.bin")
    s.add_argument("-o", "--output", required=True, help="model file to write (.h5)")
    s.add_argument("--coded-dir", help="folder for <material>.coded.h5 (default: beside -o)")
    s.add_argument("--prefer", choices=["mat", "bin"], default="mat",
                   help="dictionaries from the fp64 .mat (exact, default) or the fp16 .bin")
    s.add_argument("--json", action="store_true")
    s.set_defaults(func=run)

"""``sparsebtf decode``: reconstruct a coded BTF as a dense file and/or angular-image PNGs."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from ..errors import SparseBTFError
from ._args import check_output_dir, check_output_file

__all__ = ["register"]


def _parse_pairs(text: str) -> list[tuple[int, int]]:
    try:
        return [(int(a), int(b)) for a, b in (item.split(":") for item in text.split(","))]
    except ValueError:
        raise SparseBTFError(f"--images must look like L:V,L:V (indices), got {text!r}") from None


def run(args: argparse.Namespace) -> int:
    from ..data.dense_file import write_dense
    from ..runtime import coded_btf_view
    from ..storage import load_coded_with_model

    check_output_file(args.output, [args.coded, args.model])
    check_output_dir(args.png, "--png")
    pairs = _parse_pairs(args.images) if args.images else []
    coded = load_coded_with_model(args.coded, args.model)
    check_output_file(args.output, [coded.model_file])
    view = coded_btf_view(coded)
    if args.images:
        from ..figures import save_angular_images

        outdir = Path(args.png or ".")
        for path in save_angular_images(view, pairs, outdir):
            print(f"wrote {path}")
    if args.output:
        write_dense(args.output, view, progress=None, by="regions")
        print(f"wrote {args.output}")
    if not args.output and not args.images:
        raise SparseBTFError("nothing to do: give -o OUT.h5 and/or --images L:V,...")
    return 0


def register(sub: Any) -> None:
    s = sub.add_parser("decode", help="reconstruct a coded BTF (dense file and/or PNG images)")
    s.add_argument("coded", help="coded file from 'sparsebtf encode'")
    s.add_argument("-m", "--model", help="model file (default: the one named in the coded file)")
    s.add_argument("-o", "--output", help="dense BTF file to write (.h5)")
    s.add_argument("--images", help="angular images to write as PNG, e.g. 0:0,10:42 (light:view)")
    s.add_argument("--png", help="folder for --images (default .)")
    s.set_defaults(func=run)

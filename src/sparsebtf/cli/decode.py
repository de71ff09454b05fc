"""``sparsebtf decode``: reconstruct a coded BTF as a dense file and/or angular-image PNGs."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from ..errors import SparseBTFError
from ._args import check_output_dir, check_output_file
from ._model import MODEL_HELP
from ._output import Written
from ._write import check_btf_output, write_btf

__all__ = ["register"]


def _parse_pairs(text: str) -> list[tuple[int, int]]:
    try:
        return [(int(a), int(b)) for a, b in (item.split(":") for item in text.split(","))]
    except ValueError:
        raise SparseBTFError(f"--images must look like L:V,L:V (indices), got {text!r}") from None


def run(args: argparse.Namespace) -> int:
    from ..patch_tree import AdaptiveCodedBTF
    from ..runtime import coded_btf_view
    from ..runtime.adaptive import decoded_view
    from ..storage import load_coded_with_model

    if not args.output and not args.images:
        raise SparseBTFError("nothing to do: give -o OUT.h5 and/or --images L:V,...")
    check_output_file(args.output, [args.coded, args.model])
    check_btf_output(args.output)
    check_output_dir(args.png, "--png")
    pairs = _parse_pairs(args.images) if args.images else []
    coded = load_coded_with_model(args.coded, args.model, adaptive=True)
    check_output_file(args.output, [coded.model_file])
    view = decoded_view(coded) if isinstance(coded, AdaptiveCodedBTF) else coded_btf_view(coded)
    say = Written(args.json)
    if args.images:
        from ..figures import save_angular_images

        for light, v in pairs:
            for what, i, n in (("light", light, len(coded.lights)), ("view", v, len(coded.views))):
                if not 0 <= i < n:
                    raise SparseBTFError(f"--images {light}:{v}: {what} {i} is out of range "
                                         f"[0, {n}) (0-based light:view indices)")  # fmt: skip
        outdir = Path(args.png or ".")
        for path in save_angular_images(view, pairs, outdir):
            say.wrote(path, kind="png")
    if args.output:
        write_btf(args.output, view, "float32", say, by="regions")
    say.finish()
    return 0


def register(sub: Any) -> None:
    s = sub.add_parser("decode", help="reconstruct a coded BTF (dense file and/or PNG images)")
    s.add_argument("coded", help="coded file from 'sparsebtf encode'")
    s.add_argument("-m", "--model", help=MODEL_HELP + " (default: the one the coded file names)")
    s.add_argument("-o", "--output",
                   help="BTF file to write: .h5 (our dense file) or .btf (UBO2014, exact)")
    s.add_argument("--images", metavar="L:V,...",
                   help="angular images to write as PNG: light:view index pairs, 0-based, "
                   "e.g. 0:0,10:42")
    s.add_argument("--png", metavar="DIR", help="folder for --images (default: the current one)")
    s.add_argument("--json", action="store_true", help="print what was written as JSON")
    s.set_defaults(func=run)

"""``sparsebtf convert``: any BTF (.btf, .zip, .h5, synth:...) to our dense file."""

from __future__ import annotations

import argparse
from typing import Any

from ._args import check_output_file, open_source

__all__ = ["register"]


def run(args: argparse.Namespace) -> int:
    from ..data.dense_file import write_dense

    check_output_file(args.output, [args.input])
    if args.schema is not None:
        return rewrite_coded(args)
    btf = open_source(args.input, crop=args.crop)
    write_dense(args.output, btf, dtype=args.dtype, progress=None)
    print(f"wrote {args.output}: {btf.height}x{btf.width} texels, {len(btf.lights)} lights x "
          f"{len(btf.views)} views")
    return 0


def rewrite_coded(args: argparse.Namespace) -> int:
    """``--schema N``: a coded file rewritten in coded-file schema N, same codes, same order."""
    from pathlib import Path

    from ..errors import BTFInputError
    from ..storage import load_coded, save_coded

    if args.crop:
        raise BTFInputError("--schema rewrites a coded file as it is; --crop does not apply")
    coded = load_coded(args.input)
    save_coded(coded, args.output, schema=args.schema)
    before, after = Path(args.input).stat().st_size, Path(args.output).stat().st_size
    print(f"wrote {args.output}: coded file schema {args.schema}, {after:,} bytes (was "
          f"{before:,}: {after / before:.3f}x)")
    return 0


def register(sub: Any) -> None:
    s = sub.add_parser("convert", help="any BTF (.btf, .zip, .h5, synth:...) to our dense file")
    s.add_argument("input", metavar="IN", help="a UBO2014 .btf, UBO2003 .zip, dense or coded "
                   ".h5, or synth:CLASS[:SIZE]")
    s.add_argument("-o", "--output", required=True, help="dense BTF file to write (.h5)")
    s.add_argument("--crop", metavar="R0:R1,C0:C1",
                   help="keep rows R0..R1-1 and columns C0..C1-1 (0-based, end excluded)")
    s.add_argument("--schema", type=int, choices=[2, 3], default=None,
                   help="rewrite a coded file (from 'sparsebtf encode') in this coded-file "
                   "schema instead of decoding it: 3 (sorted locations as gaps, compressed; "
                   "what encode writes) or 2 (Table 4's uncompressed layout); the decoded "
                   "values do not change")
    s.add_argument("--dtype", choices=["float32", "float16"], default="float32",
                   help="value type of the dense file (default float32; float16 halves it)")
    s.set_defaults(func=run)

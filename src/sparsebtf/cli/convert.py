"""``sparsebtf convert``: any BTF (.btf, .zip, .h5, synth:...) to our dense file (``-o X.h5``)
or to a UBO2014 file (``-o X.btf``, exact: a stand-in for the real-data workflow)."""

from __future__ import annotations

import argparse
from typing import Any

from ._args import check_output_file, open_source
from ._output import Written
from ._write import check_btf_output, write_btf

__all__ = ["register"]


def run(args: argparse.Namespace) -> int:
    # a coded file rewritten (--schema) is a coded file; anything else is written as a BTF
    check_output_file(args.output, [args.input], kind="btf" if args.schema is None else "coded")
    if args.schema is not None:
        return rewrite_coded(args)
    check_btf_output(args.output)
    btf = open_source(args.input, crop=args.crop)
    say = Written(args.json)
    write_btf(args.output, btf, args.dtype, say)
    say.finish()
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
    s = sub.add_parser("convert", help="any BTF (.btf, .zip, .h5, synth:...) to our dense file "
                       "(.h5) or a UBO2014 file (.btf)")
    s.add_argument("input", metavar="IN", help="a UBO2014 .btf, UBO2003 .zip, dense or coded "
                   ".h5, or synth:CLASS[:SIZE]")
    s.add_argument("-o", "--output", required=True,
                   help="file to write: .h5 (our dense file) or .btf (UBO2014, DFMF, exact)")
    s.add_argument("--crop", metavar="R0:R1,C0:C1",
                   help="keep rows R0..R1-1 and columns C0..C1-1 (0-based, end excluded)")
    s.add_argument("--schema", type=int, choices=[2, 3], default=None,
                   help="rewrite a coded file (from 'sparsebtf encode') in this coded-file "
                   "schema instead of decoding it: 3 (location tables, compressed; "
                   "what encode writes) or 2 (Table 4's uncompressed layout); the decoded "
                   "values do not change")
    s.add_argument("--dtype", choices=["float32", "float16"], default="float32",
                   help="value type of the output (default float32; float16 halves it)")
    s.add_argument("--json", action="store_true", help="print what was written as JSON")
    s.set_defaults(func=run)

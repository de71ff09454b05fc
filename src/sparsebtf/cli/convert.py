"""``sparsebtf convert``: any BTF (.btf, .zip, .h5, synth:...) to our dense file (``-o X.h5``)
or to a UBO2014 file (``-o X.btf``, exact: a stand-in for the real-data workflow)."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from ..errors import SparseBTFError
from ._args import check_output_file, open_source
from ._output import Written, dense_bytes

__all__ = ["register"]


def run(args: argparse.Namespace) -> int:
    from ..data.dense_file import write_dense

    suffix = Path(args.output).suffix.lower()
    if suffix not in (".h5", ".hdf5", ".btf"):
        raise SparseBTFError(
            f"-o {args.output}: unknown extension {suffix or '(none)'!r}; give .h5 (our dense "
            "file) or .btf (a UBO2014 file)"
        )
    check_output_file(args.output, [args.input])
    btf = open_source(args.input, crop=args.crop)
    shape = (f"{btf.height}x{btf.width} texels, {len(btf.lights)} lights x {len(btf.views)} "
             "views")  # fmt: skip
    say = Written(args.json)
    if suffix == ".btf":
        from ..formats.ubo2014_write import ubo2014_bytes, write_btf_ubo2014

        kind = "half" if args.dtype == "float16" else "float"
        nbytes = ubo2014_bytes(btf.height, btf.width, len(btf.lights), len(btf.views), kind)
        say.announce(args.output, nbytes, f"UBO2014 DFMF, {shape}, {args.dtype}")
        write_btf_ubo2014(args.output, btf, kind)
    else:
        say.announce(args.output, dense_bytes(btf, args.dtype), f"{shape}, {args.dtype}")
        write_dense(args.output, btf, dtype=args.dtype, progress=None)
    say.wrote(args.output, shape, kind="ubo2014" if suffix == ".btf" else "dense",
              shape=list(btf.shape), dtype=args.dtype)  # fmt: skip
    say.finish()
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
    s.add_argument("--dtype", choices=["float32", "float16"], default="float32",
                   help="value type of the output (default float32; float16 halves it)")
    s.add_argument("--json", action="store_true", help="print what was written as JSON")
    s.set_defaults(func=run)

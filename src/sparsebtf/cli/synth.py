"""``sparsebtf synth``: render a synthetic material to a dense BTF file and/or a preview PNG."""

from __future__ import annotations

import argparse
from typing import Any

from ..errors import SparseBTFError
from ._args import check_output_file, integer, open_source
from ._output import Written
from ._write import check_btf_output, write_btf

__all__ = ["register"]


def run(args: argparse.Namespace) -> int:
    from ..data.synth import contact_sheet, synthesize

    if args.source:
        # Preview (or convert) any BTF the user has: .btf, our .h5, synth:...
        btf = open_source(args.source)
    elif args.material:
        btf = synthesize(args.material, args.size, args.directions, args.seed, black=args.black)
    else:
        raise SparseBTFError("give --class CLASS to synthesise, or --from BTF to preview a BTF")
    if not args.output and not args.preview:
        raise SparseBTFError("nothing to do: give -o OUT.h5 and/or --preview OUT.png")
    check_output_file(args.output, [args.source])
    check_btf_output(args.output)
    check_output_file(args.preview, [args.source, args.output], flag="--preview", kind="png")
    say = Written(args.json)
    if args.output:
        write_btf(args.output, btf, args.dtype, say)
        if args.preview:
            btf = open_source(args.output)
    if args.preview:
        contact_sheet(btf, args.preview)
        say.wrote(args.preview, kind="png")
    say.finish()
    return 0


def register(sub: Any) -> None:
    s = sub.add_parser("synth", help="render a synthetic material (dense BTF file, preview PNG)")
    s.add_argument(
        "--class",
        dest="material",
        help="carpet, fabric, felt, leather, stone, wallpaper, wood, or metal (perforated, "
        "high dynamic range)",
    )
    s.add_argument(
        "--from",
        dest="source",
        metavar="BTF",
        help="instead of synthesising, preview/convert this BTF (.h5, UBO2014 .btf, UBO2003 "
        ".zip, synth:...)",
    )
    s.add_argument("--size", type=int, default=64,
                   help="texels per side (default 64: 1.65 GiB at UBO2014's 151x151 directions, "
                   "said before writing; a 100x100 UBO2014 BTF file is 2.8 GB)")
    s.add_argument(
        "--directions",
        default="ubo2014",
        help="ubo2014 (151), ubo2003 (81), tiny7/13/19 (default ubo2014)",
    )
    s.add_argument("--seed", type=int, default=0,
                   help="random seed of the material's texture and geometry (default 0)")
    s.add_argument("--black", action="store_true",
                   help="true-black variant: no inter-reflection (shadows are exact zeros), "
                   "hard shadows, high dynamic range (no highlight compression)")
    s.add_argument("--dtype", choices=["float32", "float16"], default="float32",
                   help="value type of the dense file (default float32; float16 halves it)")
    s.add_argument("-o", "--output",
                   help="BTF file to write: .h5 (our dense file) or .btf (UBO2014, exact)")
    s.add_argument("--preview", help="PNG contact sheet of angular images to write")
    s.add_argument("--json", action="store_true", help="print what was written as JSON")
    s.set_defaults(func=run, checks={"size": integer(1, 16384, unit="texels per side"),
                                     "seed": integer(0, 2**32 - 1)})

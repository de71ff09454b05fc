"""``sparsebtf encode``: code one BTF on a model (§3.3), at τ or to a target size."""

from __future__ import annotations

import argparse
from typing import Any

from ..points.preprocessing import STD_MODES
from ._args import check_tau, open_source
from ._model import MODEL_HELP, check_fits, model_label, open_model_arg
from ._output import print_json

__all__ = ["register"]


def run(args: argparse.Namespace) -> int:
    from ..codec import encode, encode_to_size
    from ..storage import save_coded, storage_report

    tau = check_tau(args.tau)
    model = open_model_arg(args.model)
    label = model_label(args.model, model)
    btf = open_source(args.btf, crop=args.crop)
    check_fits(btf, model, label, args.btf)
    per_material = not args.with_dictionaries
    if args.target_ratio is not None or args.target_bytes is not None:
        coded = encode_to_size(
            btf, model, target_bytes=args.target_bytes, target_ratio=args.target_ratio,
            per_material=per_material, std_mode=args.std_mode, batch_size=args.batch,
        )
    else:
        coded = encode(
            btf,
            model,
            tau=tau or "885,64,64",
            eps=args.eps,
            std_mode=args.std_mode,
            batch_size=args.batch,
            allow_below_training=args.allow_below_training,
        )
    if model.file:
        coded.params["model_file"] = model.file
    save_coded(coded, args.output)
    report = storage_report(coded, model, args.output)
    report["model"] = {"label": label, "content_hash": model.content_hash}
    if args.json:
        print_json(report)
    else:
        print(f"wrote {args.output} with {label} ({model.content_hash[:12]}): nnz "
              f"{coded.nnz()}, file {report['file_bytes'] / 2**20:.3f} MiB")  # fmt: skip
        print(f"  {ratio_line(report, args.target_ratio, per_material)}")
    return 0


def ratio_line(report: dict[str, Any], asked: float | None, per_material: bool) -> str:
    """The compression ratio in both accountings (Table 4 bytes), the asked one first."""
    own = report["compression_ratio_per_material"]
    shared = report["compression_ratio"]
    mine = (f"ratio {own:.1f} per material (coefficients, memberships, counts)", own)
    with_d = (f"ratio {shared:.1f} counting the shared dictionaries "
              f"({report['bytes_dictionaries'] / 2**20:.2f} MiB)", shared)  # fmt: skip
    first, second = (mine, with_d) if per_material else (with_d, mine)
    asked_txt = f" (asked {asked:g})" if asked is not None else ""
    return f"{first[0]}{asked_txt}; {second[0]}"


def register(sub: Any) -> None:
    s = sub.add_parser(
        "encode", help="code one BTF on a model (default: the bundled 'release' model)",
        description="Code a BTF as sparse coefficients on a model's dictionary ensembles "
        "(paper §3.3). Without -m the bundled 'release' model is used: the authors' ensembles "
        "for UBO2014's 151 directions and 10x10 patches.",
    )
    s.add_argument("btf", metavar="BTF",
                   help="the BTF to code: dense .h5, UBO2014 .btf, UBO2003 .zip or synth:...")
    s.add_argument("-m", "--model", default=None,
                   help=MODEL_HELP + "; default: the bundled 'release' model")
    s.add_argument("-o", "--output", required=True, help="coded file to write (.h5)")
    size = s.add_mutually_exclusive_group()
    size.add_argument(
        "--tau", default=None,
        help="most coefficients per data point: 'Y,U,V' (default 885,64,64, the release's) or "
        "one integer for every channel",
    )
    size.add_argument("--target-ratio", type=float, default=None,
                      help="rate control: reach this compression ratio, per material (raw "
                      "fp16 bytes / the material's coefficient, membership and count bytes, "
                      "paper Table 4)")
    size.add_argument("--target-bytes", type=int, default=None,
                      help="rate control: reach this many bytes of the material's codes "
                      "(paper Table 4 accounting)")
    s.add_argument("--with-dictionaries", action="store_true",
                   help="targets also count the shared dictionaries (K x 3 channels, about "
                   "2.1 MiB for the release model), as Table 4's totals do")
    s.add_argument("--per-material", action="store_true", help=argparse.SUPPRESS)
    s.add_argument("--eps", type=float, default=1e-5,
                   help="stop adding coefficients to a point once its mean squared residual "
                   "(standardised log-YUV) is below this (default 1e-5)")
    s.add_argument("--std-mode", choices=STD_MODES, default=None,
                   help="standardisation of the material: shared (one mean/std for Y, U, V, "
                   "the release's) or per_channel (default: the model's)")
    s.add_argument("--batch", type=int, default=4,
                   help="data points read and coded at a time (memory bound; default 4)")
    s.add_argument("--crop", metavar="R0:R1,C0:C1",
                   help="code only rows R0..R1-1 and columns C0..C1-1 (0-based, end excluded)")
    s.add_argument("--allow-below-training", action="store_true",
                   help="accept a tau below the model's training sparsity tau_l (the paper "
                   "requires tau >= tau_l)")
    s.add_argument("--json", action="store_true", help="print the storage report as JSON")
    s.set_defaults(func=run)

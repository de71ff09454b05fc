"""``sparsebtf encode``: code one BTF on a model (§3.3), at τ or to a target size."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from ..points.preprocessing import STD_MODES
from ._args import check_output_file, check_tau, integer, number, open_source
from ._output import print_json

__all__ = ["register"]


def run(args: argparse.Namespace) -> int:
    from ..codec import encode, encode_to_size
    from ..storage import load_model, save_coded, storage_report

    tau = check_tau(args.tau)
    check_output_file(args.output, [args.btf, args.model])
    model = load_model(args.model)
    btf = open_source(args.btf, crop=args.crop)
    if args.target_ratio is not None or args.target_bytes is not None:
        coded = encode_to_size(
            btf, model, target_bytes=args.target_bytes, target_ratio=args.target_ratio,
            per_material=args.per_material, std_mode=args.std_mode, batch_size=args.batch,
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
    coded.params["model_file"] = str(Path(args.model).resolve())
    save_coded(coded, args.output)
    report = storage_report(coded, model, args.output)
    if args.json:
        print_json(report)
    else:
        print(
            f"wrote {args.output}: nnz {coded.nnz()}, {report['bytes_total'] / 2**20:.3f} MiB "
            f"(paper accounting), ratio {report['compression_ratio']:.1f}, file "
            f"{report['file_bytes'] / 2**20:.3f} MiB"
        )
    return 0


def register(sub: Any) -> None:
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
        "--std-mode", choices=STD_MODES, default=None, help="default: the model's"
    )
    s.add_argument("--batch", type=int, default=4)
    s.add_argument("--crop", help="encode only rows R0:R1 and columns C0:C1")
    s.add_argument(
        "--allow-below-training", action="store_true", help="accept tau below the training sparsity"
    )
    s.add_argument("--json", action="store_true")
    s.set_defaults(func=run, checks={
        "eps": number(0, unit="(residual mean squared error, standardised)"),
        "target_ratio": number(1, unit="(raw bytes / coded bytes)"),
        "target_bytes": integer(1, unit="bytes"),
        "batch": integer(1, 4096, unit="data points per batch"),
    })  # fmt: skip

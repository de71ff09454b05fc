"""``sparsebtf encode``: code BTFs on a model (§3.3), at τ or to a target size, in this process
or on a Dask cluster (``--workers`` / ``--scheduler``)."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from ..points.preprocessing import STD_MODES
from ._args import add_cluster_options, check_tau, cluster_options, output_files, parse_crop
from ._output import print_json

__all__ = ["register"]


def run(args: argparse.Namespace) -> int:
    from ..codec import encode_many
    from ..storage import load_model, save_coded, storage_report

    tau = check_tau(args.tau)
    outputs = output_files(args.btf, args.output)
    model = load_model(args.model)
    coded_all = encode_many(
        args.btf, model, tau=tau, eps=args.eps, target_bytes=args.target_bytes,
        target_ratio=args.target_ratio, per_material=args.per_material, std_mode=args.std_mode,
        batch_size=args.batch, allow_below_training=args.allow_below_training,
        crop=parse_crop(args.crop), **cluster_options(args),
    )  # fmt: skip
    reports = []
    for coded, output in zip(coded_all, outputs, strict=True):
        coded.params["model_file"] = str(Path(args.model).resolve())
        save_coded(coded, output)
        report = storage_report(coded, model, output)
        reports.append({"input": coded.name, "output": str(output), **report})
        if not args.json:
            print(
                f"wrote {output}: nnz {coded.nnz()}, {report['bytes_total'] / 2**20:.3f} MiB "
                f"(paper accounting), ratio {report['compression_ratio']:.1f}, file "
                f"{report['file_bytes'] / 2**20:.3f} MiB"
            )
    if args.json:
        print_json(reports[0] if len(args.btf) == 1 else {"files": reports})
    return 0


def register(sub: Any) -> None:
    s = sub.add_parser("encode", help="code BTFs on a model")
    s.add_argument("btf", metavar="BTF", nargs="+", help="the BTFs to code (.h5, .btf, .zip or "
                   "synth:...)")
    s.add_argument("-m", "--model", required=True, help="model file from 'sparsebtf train'")
    s.add_argument("-o", "--output", required=True,
                   help="coded file to write (.h5), or a folder (DIR/) for one NAME.coded.h5 per "
                   "input (needed for several inputs)")
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
    add_cluster_options(s)
    s.add_argument("--json", action="store_true")
    s.set_defaults(func=run)

"""``sparsebtf eval``: quality (MSE, PSNR, SSIM) and storage of a coded BTF vs its reference."""

from __future__ import annotations

import argparse
from typing import Any

import numpy as np

from ._args import integer, open_source
from ._output import print_json, table

__all__ = ["register"]

#: Storage figures reported beside the quality metrics.
_STORAGE_KEYS = (
    "nnz",
    "bytes_coefficients",
    "bytes_dictionaries",
    "bytes_stats",
    "bytes_total",
    "bytes_raw",
    "compression_ratio",
    "file_bytes",
)


def run(args: argparse.Namespace) -> int:
    from ..metrics import compare
    from ..runtime import coded_btf_view
    from ..storage import load_coded_with_model, storage_report

    coded = load_coded_with_model(args.coded, args.model)
    reference = open_source(args.reference, crop=args.crop)
    metrics = compare(
        reference, coded_btf_view(coded), stats=coded.stats, ssim_images=args.ssim_images
    )
    metrics["mse_std_codes"] = float(
        np.mean([coded.codes[ch].errors.mean() for ch in coded.channels])
    )
    report = storage_report(coded, coded.model, args.coded)
    out = {**metrics, **{k: report[k] for k in _STORAGE_KEYS}}
    if args.json:
        print_json(out)
    else:
        print(table([(k, v) for k, v in out.items()]))
    return 0


def register(sub: Any) -> None:
    s = sub.add_parser("eval", help="quality and storage of a coded BTF against its reference")
    s.add_argument("coded", help="coded file from 'sparsebtf encode'")
    s.add_argument("--reference", required=True, metavar="BTF", help="the original BTF")
    s.add_argument("-m", "--model", help="model file (default: the one named in the coded file)")
    s.add_argument("--crop", help="crop the reference like the coded BTF was cropped")
    s.add_argument(
        "--ssim-images", type=int, default=16, help="angular images sampled for SSIM (default 16)"
    )
    s.add_argument("--json", action="store_true")
    s.set_defaults(func=run, checks={"ssim_images": integer(0, 10**6, unit="angular images")})

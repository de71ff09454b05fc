"""``sparsebtf eval``: quality (MSE, PSNR, SSIM) and storage of a coded BTF vs its reference."""

from __future__ import annotations

import argparse
from typing import Any

import numpy as np

from ._args import integer, open_source
from ._model import MODEL_HELP
from ._output import (
    add_allow_nonfinite,
    check_finite_result,
    format_value,
    label,
    nested_rows,
    print_json,
    table,
)

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
    "compression_ratio_per_material",
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
    identical = ("psnr_rgb",) if out["mse_rgb"] == 0 else ()
    check_finite_result(out, "eval", args.allow_nonfinite, exact=identical)
    if args.json:
        print_json(out)
    else:
        print(quality_table(out))
    return 0


def quality_table(out: dict[str, Any]) -> str:
    """The numbers of ``eval`` as a table in words (:func:`.label`) with units: the quality
    metrics, the storage figures, then any other field the result has."""
    ssim = ("not computed (--ssim-images 0)" if out.get("ssim") is None else
            f"{out['ssim']:.4f} (mean over {out['ssim_images']} angular images, data range "
            f"{out['ssim_data_range']:.4g})")  # fmt: skip
    shown = {
        "mse_rgb": f"{out['mse_rgb']:.4g}",
        "psnr_rgb": f"{out['psnr_rgb']:.2f} dB (peak {out['peak']:g})",
        "ssim": ssim,
        "max_decoded": _largest(out),
        "top_error_share": f"{100 * out['top_error_share']:.1f} % of the squared error",
        "mse_log": f"{out['mse_log']:.4g}",
        "mse_std": f"{out['mse_std']:.4g} (the codes' residual: {out['mse_std_codes']:.4g})",
        "nnz": format_value(out["nnz"]),
        "bytes_coefficients": f"{out['bytes_coefficients']:,}",
        "bytes_dictionaries": f"{out['bytes_dictionaries']:,}",
        "bytes_stats": f"{out['bytes_stats']:,}",
        "bytes_raw": f"{out['bytes_raw']:,}",
        "compression_ratio_per_material": f"{out['compression_ratio_per_material']:.1f}",
        "compression_ratio": f"{out['compression_ratio']:.1f}",
        "file_bytes": f"{out['file_bytes']:,}",
    }
    in_other_rows = {"peak", "ssim_images", "ssim_data_range", "mse_std_codes", "reference_max"}
    rest = {k: v for k, v in out.items() if k not in shown and k not in in_other_rows}
    return table([(label(k), v) for k, v in shown.items()] + nested_rows(rest))


def _largest(out: dict[str, Any]) -> str:
    """The largest decoded value beside the reference's (a firework shows as a big ratio)."""
    top, ref = out["max_decoded"], out["reference_max"]
    if ref <= 0:
        return f"{top:.4g}"
    return f"{top:.4g}, the reference's largest {ref:.4g} ({top / ref:.3g}x)"


def register(sub: Any) -> None:
    s = sub.add_parser("eval", help="quality and storage of a coded BTF against its reference")
    s.add_argument("coded", help="coded file from 'sparsebtf encode'")
    s.add_argument("--reference", required=True, metavar="BTF",
                   help="the original BTF: dense .h5, UBO2014 .btf, UBO2003 .zip or synth:...")
    s.add_argument("-m", "--model", help=MODEL_HELP + " (default: the one the coded file names)")
    s.add_argument("--crop", metavar="R0:R1,C0:C1",
                   help="crop the reference as the coded BTF was cropped (0-based, end excluded)")
    s.add_argument(
        "--ssim-images", type=int, default=16, help="angular images sampled for SSIM (default 16)"
    )
    s.add_argument("--json", action="store_true", help="print one JSON object")
    add_allow_nonfinite(s)
    s.set_defaults(func=run, checks={"ssim_images": integer(0, 10**6, unit="angular images")})

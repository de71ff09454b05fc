"""``sparsebtf eval``: quality (MSE of linear, log and display-mapped RGB, PSNR, SSIM) and
storage of a coded BTF vs its reference."""

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

#: Storage figures reported beside the quality metrics (see storage_report).
_STORAGE_KEYS = (
    "nnz",
    "bytes_coefficients",
    "bytes_membership_counts",
    "bytes_table4_material",
    "bytes_dictionaries",
    "bytes_stats",
    "bytes_total",
    "bytes_raw",
    "compression_ratio",
    "compression_ratio_table4_material",
    "bytes_stored_codes",
    "bytes_stored_stats",
    "bytes_stored_directions",
    "bytes_stored_header",
    "bytes_stored",
    "compression_ratio_per_material",
    "stored_codes_vs_table4",
    "file_bytes",
)


def run(args: argparse.Namespace) -> int:
    from ..metrics import compare
    from ..patch_tree import AdaptiveCodedBTF
    from ..runtime import coded_btf_view
    from ..runtime.adaptive import decoded_view
    from ..storage import load_coded_with_model, storage_report
    from ..storage.adaptive_file import adaptive_report

    coded = load_coded_with_model(args.coded, args.model, adaptive=True)
    adaptive = isinstance(coded, AdaptiveCodedBTF)
    reference = open_source(args.reference, crop=args.crop)
    view = decoded_view(coded) if adaptive else coded_btf_view(coded)
    metrics = compare(reference, view, stats=coded.stats, ssim_images=args.ssim_images)
    if adaptive:  # each node's residual per value, weighted by its texels
        nodes = coded.tree.nodes
        per = [np.concatenate([layer.codes[ch].errors[coded.tree.points(p)]
                               for p, layer in coded.layers.items()])
               for ch in coded.channels]  # fmt: skip
        area = np.concatenate([nodes[nodes[:, 2] == p, 2] ** 2 for p in coded.layers])
        metrics["mse_std_codes"] = float(np.mean([np.average(e, weights=area) for e in per]))
        report = adaptive_report(coded, coded.model, args.coded)
    else:
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
    """The numbers of ``eval`` as a table in words with units: the quality metrics, the
    bytes actually stored (adding up to the file), Table 4's bytes, then any other field the
    result has (:func:`.label`)."""
    ssim = ("not computed (--ssim-images 0)" if out.get("ssim") is None else
            f"{out['ssim']:.4f} (mean over {out['ssim_images']} angular images, data range "
            f"{out['ssim_data_range']:.4g})")  # fmt: skip
    rows = [
        ("MSE, linear RGB", f"{out['mse_rgb']:.4g}"),
        ("PSNR, linear RGB", f"{out['psnr_rgb']:.2f} dB (peak {out['peak']:g})"),
        ("SSIM", ssim),
        (label("max_decoded"), _largest(out)),
        (label("top_error_share"), f"{100 * out['top_error_share']:.1f} % of the squared error"),
        ("MSE, log RGB", f"{out['mse_log']:.4g}"),
        ("MSE, display-mapped", f"{out['mse_display']:.4g} (clip(1.3 x^(1/1.8), 0, 1), as the "
                                "paper displays images)"),
        ("MSE, standardised", f"{out['mse_std']:.4g} (the codes' residual: "
                              f"{out['mse_std_codes']:.4g})"),
        ("coefficients", format_value(out["nnz"])),
        ("raw bytes (fp16)", f"{out['bytes_raw']:,}"),
        ("stored: codes", f"{out['bytes_stored_codes']:,} bytes "
                          f"({out['stored_codes_vs_table4']:.2f} x Table 4's)"),
        ("stored: statistics", f"{out['bytes_stored_stats']:,} bytes"),
        ("stored: directions", f"{out['bytes_stored_directions']:,} bytes"),
        ("stored: header", f"{out['bytes_stored_header']:,} bytes"),
        ("stored: file", f"{out['bytes_stored']:,} bytes (the material; the model is shared)"),
        ("ratio per material", f"{out['compression_ratio_per_material']:.1f} (raw / file bytes)"),
        ("Table 4: material", f"{out['bytes_table4_material']:,} bytes (coefficients "
                              f"{out['bytes_coefficients']:,}, memberships and counts "
                              f"{out['bytes_membership_counts']:,}), ratio "
                              f"{out['compression_ratio_table4_material']:.1f}"),
        ("Table 4: with dictionaries", f"{out['bytes_total']:,} bytes (dictionaries "
                                       f"{out['bytes_dictionaries']:,}, shared by every "
                                       f"material), ratio {out['compression_ratio']:.1f}"),
    ]  # fmt: skip
    shown = {"mse_rgb", "psnr_rgb", "peak", "ssim", "ssim_images", "ssim_data_range",
             "max_decoded", "reference_max", "top_error_share", "mse_log", "mse_display",
             "mse_std", "mse_std_codes", "nnz", *_STORAGE_KEYS}  # fmt: skip
    rest = {k: v for k, v in out.items() if k not in shown}
    return table(rows + nested_rows(rest))


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

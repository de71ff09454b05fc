"""``sparsebtf encode``: code BTFs on a model (§3.3), at τ or to a target size, in this process
or on a Dask cluster (``--workers`` / ``--scheduler``)."""

from __future__ import annotations

import argparse
from typing import Any

from ..codec.options import EncodeOptions
from ..errors import SparseBTFError, UnreachableTargetError
from ..learning.objective import OBJECTIVES
from ..points.preprocessing import STD_MODES
from ._args import (
    add_cluster_options,
    build_options,
    check_output_dir,
    check_resume,
    check_tau,
    checkpoint_dir,
    cluster_options,
    given_int,
    integer,
    log_offset,
    number,
    open_source,
    option_checks,
    output_files,
    parse_crop,
    resumable,
)
from ._model import MODEL_HELP, check_fits, model_label, open_model_arg
from ._output import format_value, print_json

__all__ = ["register"]

#: The library's defaults, which the flags show and take.
DEFAULTS = EncodeOptions()
#: The numeric options and their flags: checked before the command by the library's table.
FLAGS = {"eps": "--eps", "candidates": "--candidates", "batch_size": "--batch"}


def run(args: argparse.Namespace) -> int:
    from ..codec.checkpoint import EncodeCheckpoint

    tau = check_tau(args.tau)
    ck = checkpoint_dir(args)
    options = build_options(
        EncodeOptions, FLAGS, eps=args.eps,
        candidates=None if args.exhaustive else args.candidates, objective=args.objective,
        allow_below_training=args.allow_below_training, std_mode=args.std_mode,
        log_offset=log_offset(args.log_offset), batch_size=args.batch,
        crop=parse_crop(args.crop), checkpoint_dir=ck, adaptive_patches=args.adaptive_patches,
        highlights=args.highlights,
    )  # fmt: skip
    outputs = output_files(args.btf, args.output, inputs=[args.model])
    check_output_dir(str(ck), "--checkpoint-dir")
    check_resume(ck, args.resume, "points_*.npz", "encode")
    try:
        with resumable(ck):
            _encode(args, tau, options, outputs)
    except UnreachableTargetError:
        EncodeCheckpoint(ck).remove()  # ranges coded for this target serve no other run
        raise
    EncodeCheckpoint(ck).remove()  # every output is written: the ranges have served
    return 0


def _encode(args: argparse.Namespace, tau: str | None, options: EncodeOptions,
            outputs: list[Any]) -> None:  # fmt: skip
    from ..codec import encode_many
    from ..execution import Execution
    from ..storage import storage_report

    model = open_model_arg(args.model)
    label = model_label(args.model, model)
    # One line, before any work, for an input the model cannot code (here, not on a worker,
    # so the message can name the commands that fix it).
    for source in args.btf:
        btf = open_source(source, crop=args.crop)
        check_fits(btf, model, label, source)
        raw = btf.n_values * 2  # fp16, the ratio's numerator (paper Table 4)
        if args.target_bytes is not None and args.target_bytes > raw:
            raise SparseBTFError(
                f"--target-bytes {args.target_bytes:,} is more than {source}'s raw size "
                f"({raw:,} bytes in fp16): the ratio would be below 1"
            )
    per_material = not args.with_dictionaries
    sized = args.target_bytes is not None or args.target_ratio is not None
    if args.adaptive_patches:
        _encode_adaptive(args, tau, options, outputs, model, label)
        return
    args.budget = args.budget or "stored"
    target = {"target_bytes": args.target_bytes, "target_ratio": args.target_ratio,
              "per_material": per_material, "budget": args.budget} if sized else {"tau": tau}
    coded_all = encode_many(args.btf, model, **target, options=options,
                            execution=Execution(**cluster_options(args)))  # fmt: skip
    reports = []
    for coded, output in zip(coded_all, outputs, strict=True):
        report = _save(coded, output, model, label, storage_report, reports)
        if not args.json:
            print(f"wrote {output} with {label} ({model.content_hash[:12]}): "
                  f"{coefficients_text(coded)}, file {report['file_bytes']:,} bytes")  # fmt: skip
            print(f"  {ratio_line(report, args.target_ratio, args.budget, per_material)}")
    if args.json:
        print_json(reports[0] if len(args.btf) == 1 else {"files": reports})


def _encode_adaptive(args: argparse.Namespace, tau: str | None, options: EncodeOptions,
                     outputs: list[Any], model: Any, label: str) -> None:  # fmt: skip
    """``--adaptive-patches``: each BTF's quadtree chosen by rate and distortion
    (:mod:`sparsebtf.codec.adaptive`); a target counts Table 4 bytes with the tree."""
    from ..codec.adaptive import encode_adaptive
    from ..execution import Execution
    from ..learning.codes import RELEASE_TAU
    from ..storage.adaptive_file import adaptive_report

    if args.budget == "stored" or args.with_dictionaries:
        raise SparseBTFError(
            "--adaptive-patches: a target counts the material's Table 4 bytes with its tree "
            "(--budget paper, without --with-dictionaries); "
            + ("--budget stored" if args.budget == "stored" else "--with-dictionaries")
            + " is not supported with it yet"
        )
    reports = []
    for source, output in zip(args.btf, outputs, strict=True):
        coded = encode_adaptive(source, model, tau or RELEASE_TAU, target_bytes=args.target_bytes,
                                target_ratio=args.target_ratio, options=options,
                                execution=Execution(**cluster_options(args)))  # fmt: skip
        report = _save(coded, output, model, label, adaptive_report, reports)
        if not args.json:
            nodes = ", ".join(f"{n} of {p}x{p}" for p, n in coded.tree.counts().items())
            print(f"wrote {output} with {label} ({model.content_hash[:12]}): adaptive patch "
                  f"sizes, nodes {nodes}; coefficients {format_value(coded.nnz())}, file "
                  f"{report['file_bytes']:,} bytes")  # fmt: skip
            print(f"  {ratio_line(report, args.target_ratio, 'paper', True)} (tree "
                  f"{report['bytes_tree']:,} bytes)")  # fmt: skip
    if args.json:
        print_json(reports[0] if len(args.btf) == 1 else {"files": reports})


def _save(coded: Any, output: Any, model: Any, label: str, report_of: Any,
          reports: list[dict[str, Any]]) -> dict[str, Any]:  # fmt: skip
    """Write ``coded`` (naming its model file) and append its storage report to ``reports``
    (``report_of``: the fixed-size or the adaptive accounting); the report."""
    from ..storage import save_coded

    if model.file:
        coded.params["model_file"] = model.file
    save_coded(coded, output)
    report = report_of(coded, model, output)
    report["model"] = {"label": label, "content_hash": model.content_hash}
    reports.append({"input": coded.name, "output": str(output), **report})
    return report


def coefficients_text(coded: Any) -> str:
    """The coefficients kept, said as totals over the points, with τ and the mean per point
    beside them (the totals of ``--tau 32,8,8`` on 4 points read "Y 128", not τ)."""
    n = coded.n_points
    tau = coded.params.get("tau")
    mean = {ch: round(c.nnz / n, 1) if n else 0.0 for ch, c in coded.codes.items()}
    per_point = f"τ {format_value(tau)}, " if isinstance(tau, dict) else ""
    return (f"coefficients {format_value(coded.nnz())} over all {n:,} points (per point: "
            f"{per_point}mean {format_value(mean)})")  # fmt: skip


def ratio_line(
    report: dict[str, Any], asked: float | None, budget: str = "stored", per_material: bool = True
) -> str:
    """The compression ratio in both accountings, the one a target asked for first: stored
    (raw / the file's bytes: codes, statistics, directions, header) and the paper's Table 4
    (per material, and with the shared dictionaries)."""
    stored = (f"ratio {report['compression_ratio_per_material']:.1f} per material (raw / "
              f"{report['bytes_stored']:,} file bytes)")  # fmt: skip
    parts = "coefficients, memberships, counts" + (
        f", highlight store {report['bytes_highlights']:,}" if report.get("bytes_highlights")
        else "")  # fmt: skip
    t4 = (f"Table 4: ratio {report['compression_ratio_table4_material']:.1f} per material "
          f"({parts}: {report['bytes_table4_material']:,} bytes)")
    t4d = (f"{report['compression_ratio']:.1f} counting the shared dictionaries "
           f"({report['bytes_dictionaries'] / 2**20:.2f} MiB)")  # fmt: skip
    asked_txt = f" (asked {asked:g})" if asked is not None else ""
    if budget == "paper" and not per_material:
        return f"Table 4: ratio {t4d}{asked_txt}; {t4}; {stored}"
    if budget == "paper":
        return f"{t4}{asked_txt}, {t4d}; {stored}"
    return f"{stored}{asked_txt}; {t4}, {t4d}"


def register(sub: Any) -> None:
    s = sub.add_parser(
        "encode", help="code BTFs on a model (default: the bundled 'release' model)",
        description="Code BTFs as sparse coefficients on a model's dictionary ensembles "
        "(paper §3.3), in this process or on a Dask cluster (--workers, --scheduler). Without "
        "-m the bundled 'release' model is used: the authors' ensembles for UBO2014's 151 "
        "directions and 10x10 patches.",
    )
    s.add_argument("btf", metavar="BTF", nargs="+",
                   help="the BTFs to code: dense .h5, UBO2014 .btf, UBO2003 .zip or synth:...")
    s.add_argument("-m", "--model", default=None,
                   help=MODEL_HELP + "; default: the bundled 'release' model")
    s.add_argument("-o", "--output", required=True,
                   help="coded file to write (.h5), or a folder (DIR/) for one NAME.coded.h5 per "
                   "input (needed for several inputs)")
    size = s.add_mutually_exclusive_group()
    size.add_argument(
        "--tau", default=None,
        help="most coefficients per data point: 'Y,U,V' (default 885,64,64, the release's) or "
        "one integer for every channel",
    )
    size.add_argument("--target-ratio", type=float, default=None,
                      help="rate control: reach this compression ratio per material: raw fp16 "
                      "bytes / the coded file's bytes (--budget stored, the default), or / "
                      "the material's coefficient, membership and count bytes of the paper's "
                      "Table 4 (--budget paper)")
    size.add_argument("--target-size", "--target-bytes", dest="target_bytes", type=int,
                      default=None, metavar="BYTES",
                      help="rate control: reach this many bytes: the coded file's size "
                      "(--budget stored) or the material's Table 4 bytes (--budget paper)")
    s.add_argument("--budget", choices=("stored", "paper"), default=None,
                   help="what a target counts: 'stored', the bytes of the coded file, within "
                   "0.4%% below (default); 'paper', Table 4's bytes, within one coefficient")
    s.add_argument("--with-dictionaries", action="store_true",
                   help="with --budget paper: targets also count the shared dictionaries (K x "
                   "3 channels, about 2.1 MiB for the release model), as Table 4's totals do")
    s.add_argument("--adaptive-patches", action="store_true",
                   help="adaptive patch sizes, on a model trained with several (train --patch "
                   "20,10,5): each block of the largest size is one data point or splits into "
                   "smaller ones, chosen by rate and distortion at the byte budget: --target-size "
                   "/ --target-ratio (Table 4 bytes with the tree), or with --tau the bytes of the "
                   "fixed code at tau, --eps in blocks of the largest size (docs/format.md §3, "
                   "adaptive patch sizes)")
    s.add_argument("--eps", type=float, default=DEFAULTS.eps,
                   help="stop adding coefficients to a point once its mean squared residual "
                   "(standardised log-YUV; with --objective linear/display, that objective's "
                   f"first-order error) is below this (default {DEFAULTS.eps:g})")
    s.add_argument("--std-mode", choices=STD_MODES, default=None,
                   help="standardisation of the material: shared (one mean/std for Y, U, V, "
                   "the release's) or per_channel (default: the model's)")
    s.add_argument("--log-offset", default=DEFAULTS.log_offset, metavar="auto|release|OFFSET",
                   help="the offset of ln(x + offset): auto (default) = 1%% of the "
                   "material's median positive value, at least 1e-5, so exact zeros (hard "
                   "shadows, masked texels) do not dominate the code; release = 1e-5, the "
                   "authors' preprocessing; or a number in [1e-5, 1e3]")
    rule = s.add_mutually_exclusive_group()
    # given_int: argparse lets an excluded option through when its value is the default's
    # object (--candidates 2 --exhaustive)
    rule.add_argument("--candidates", type=given_int, default=DEFAULTS.candidates, metavar="N",
                      help="dictionaries projected exactly per data point and channel, after a "
                      "screening by partial projections ranks all K (default "
                      f"{DEFAULTS.candidates}; K or more: every dictionary)")
    rule.add_argument("--exhaustive", action="store_true",
                      help="project every data point on every dictionary (the paper's rule; "
                      "the default screening projects it on --candidates of them)")
    s.add_argument("--objective", choices=OBJECTIVES, default=DEFAULTS.objective,
                   help="the error each point's dictionary and count are chosen by: log "
                   "(default, the paper's rule: the standardised log-YUV error), linear (the "
                   "error of linear RGB, the radiance a renderer integrates: for glossy "
                   "highlights) or display (after the display mapping 1.3*I^(1/1.8), clipped "
                   "at 1); --eps is then in its units (mean squared error per value)")
    s.add_argument("--highlights", nargs="?", const="lobes", default=False,
                   choices=["lobes", "entries"],
                   help="with --tau: spend tau's bytes on the codes at tau or fewer "
                   "coefficients plus linear-RGB corrections (8-bit floats, or one 8-bit "
                   "scale of the data point's tint) at the (texel, light, view) nodes where "
                   "they remove the most error, and a glossy lobe per texel where it pays, "
                   "whichever errs least (glossy materials; the file is schema 7 or 8, "
                   "docs/format.md); '--highlights entries' skips the lobes (their "
                   "fit takes seconds per data point)")
    s.add_argument("--batch", type=int, default=DEFAULTS.batch_size,
                   help="data points read and coded at a time (memory bound; default "
                   f"{DEFAULTS.batch_size})")
    s.add_argument("--crop", metavar="R0:R1,C0:C1",
                   help="code only rows R0..R1-1 and columns C0..C1-1 (0-based, end excluded)")
    s.add_argument("--allow-below-training", action="store_true",
                   help="accept a tau below the model's training sparsity tau_l (the paper "
                   "requires tau >= tau_l)")
    s.add_argument("--checkpoint-dir",
                   help="save each finished range of data points here (default: "
                   "OUTPUT.checkpoint beside the output, removed once every output is written)")
    s.add_argument("--resume", action="store_true",
                   help="continue an interrupted or killed run from its finished ranges (same "
                   "inputs and options; an error names what differs); the output equals an "
                   "uninterrupted run's")
    add_cluster_options(s)
    s.add_argument("--json", action="store_true", help="print the storage report(s) as JSON")
    # the targets' ranges, and the options' by EncodeOptions' table (again, with the rest,
    # when the command builds the options: build_options)
    s.set_defaults(func=run, checks={
        "target_ratio": number(1, unit="(raw bytes / coded bytes)"),
        "target_bytes": integer(1, unit="bytes"),
        **option_checks(EncodeOptions, FLAGS),
    })  # fmt: skip

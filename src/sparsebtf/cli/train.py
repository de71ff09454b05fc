"""``sparsebtf train``: learn a model (three dictionary ensembles) from BTFs (§3.2), in this
process or on a Dask cluster (``--workers`` / ``--scheduler``), saving a checkpoint after each
iteration (``--resume`` continues an interrupted run)."""

from __future__ import annotations

import argparse
import shutil
from pathlib import Path
from typing import Any

from ..learning.ensemble import (
    CANDIDATES,
    EXHAUSTIVE_MAX_ENTRIES,
    FULL_PASS_EVERY,
    INITS,
)
from ..points.preprocessing import STD_MODES
from ._args import (
    add_cluster_options,
    check_output_dir,
    check_output_file,
    check_resume,
    checkpoint_dir,
    cluster_options,
    integer,
    log_offset,
    number,
    open_source,
    parse_crop,
    resumable,
)
from ._output import print_json

__all__ = ["register"]


def run(args: argparse.Namespace) -> int:
    from ..storage import save_model

    check_output_file(args.output, args.btfs, kind="model")
    from ..codec.train import checkpoint_path

    ck = checkpoint_dir(args)
    check_output_dir(str(ck), "--checkpoint-dir")
    check_resume(ck, args.resume, Path(checkpoint_path(ck, "*")).name, "train")
    for s in args.btfs:  # one clear line for a bad input, before any work
        open_source(s, crop=args.crop)
    with resumable(ck):
        model = _train(args, ck)
    save_model(model, args.output)
    if not args.checkpoint_dir:  # the default folder has served its purpose
        shutil.rmtree(ck, ignore_errors=True)
    _report(args, model)
    return 0


def _train(args: argparse.Namespace, ck: Path) -> Any:
    from ..codec import train

    return train(
        args.btfs,
        n_dictionaries=args.dicts,
        tau_train=args.tau_train,
        tau_validation=args.tau_validation,
        init=args.init,
        patch=args.patch,
        sample=args.sample,
        max_iter=args.iters,
        tol=args.tol,
        std_mode=args.std_mode,
        log_offset=log_offset(args.log_offset),
        colour_mode=args.colour_mode,
        candidates=args.candidates,
        full_pass_every=args.full_pass_every,
        batch_size=args.batch,
        seed=args.seed,
        checkpoint_dir=str(ck),
        crop=parse_crop(args.crop),
        **cluster_options(args),
    )


def _report(args: argparse.Namespace, model: Any) -> None:
    summary = {
        "model": args.output,
        "content_hash": model.content_hash,
        "channels": list(model.channels),
        "mode_sizes": list(model.mode_sizes),
        "training": model.training,
    }
    if args.json:
        print_json(summary)
    else:
        for ch, t in model.training.items():
            print(
                f"{ch}: {t['n_points']} points, {t['n_iter']} iterations, objective "
                f"{t['objective'][0]:.4g} -> {t['objective'][-1]:.4g}, points per dictionary "
                f"{'/'.join(map(str, t['membership_counts']))}, {t['seconds']:.1f} s"
            )
        print(f"wrote {args.output} (model {model.content_hash[:12]})")


def register(sub: Any) -> None:
    s = sub.add_parser("train", help="learn a model (three dictionary ensembles) from BTFs")
    s.add_argument("btfs", nargs="+", metavar="BTF",
                   help="training BTFs: dense .h5, UBO2014 .btf, UBO2003 .zip or "
                   "synth:CLASS[:SIZE[:SEED]]")
    s.add_argument("-o", "--output", required=True, help="model file to write (.h5)")
    s.add_argument("--dicts", type=int, default=8, help="dictionaries per ensemble K (default 8)")
    s.add_argument(
        "--tau-train",
        default="256,32,32",
        help="training sparsity per channel Y,U,V (default 256,32,32); several levels "
        "split the dictionaries evenly over them, e.g. 64,8,8/256,32,32/885,64,64 (--dicts a "
        "multiple of their number); 'learn' (or learn:LEVELS) chooses each dictionary's level "
        "from the grid 64,8,8/256,32,32/885,64,64 by the error on a held-out fifth of the "
        "training points (3 fits: see docs/benchmarks.md)",
    )
    s.add_argument("--tau-validation", metavar="LEVELS",
                   help="with --tau-train learn: the coding tau_t the validation error is "
                   "measured at, e.g. 885,64,64 or 326,40,40/885,64,64 (default: the grid's "
                   "levels); give the tau_t you will encode at")
    s.add_argument("--init", choices=INITS, default="points",
                   help="initial dictionaries: points (default: the HOSVD of K random "
                   "training points), random, or preclustered (the HOSVD of K groups of points "
                   "with alike sparsity patterns under a DCT basis)")
    s.add_argument("--patch", type=int, default=10, help="spatial patch size p (default 10)")
    s.add_argument(
        "--sample",
        type=float,
        default=0.1,
        help="fraction of each BTF's data points used (default 0.1)",
    )
    s.add_argument("--iters", type=int, default=10, help="maximum iterations (default 10)")
    s.add_argument(
        "--tol",
        type=float,
        default=1e-4,
        help="stop below this relative objective decrease (default 1e-4)",
    )
    s.add_argument(
        "--std-mode",
        choices=STD_MODES,
        default="shared",
        help="standardisation: the release's shared mean/std, or per channel",
    )
    s.add_argument("--log-offset", default="auto", metavar="auto|release|EPS",
                   help="the offset eps of ln(x + eps) of each training BTF: auto (default) = "
                   "1%% of its median positive value, at least 1e-5; release = 1e-5, the "
                   "authors'; or a number in [1e-5, 1e3]")
    s.add_argument(
        "--colour-mode",
        action="store_true",
        help="one 5D ensemble with colour as a mode (paper Table 6)",
    )
    s.add_argument(
        "--candidates",
        type=int,
        default=None,
        help="dictionaries tried per point between full coding passes: its best ones at the "
        "last full pass (default: all K, the exhaustive trainer, when a full pass is cheap: "
        f"points x K x point size <= 2^{EXHAUSTIVE_MAX_ENTRIES.bit_length() - 1}, e.g. 29 "
        f"points of 10x10x151x151 at K = 8; else {CANDIDATES}; >= --dicts tries all K every "
        "iteration)",
    )
    s.add_argument(
        "--full-pass-every",
        type=int,
        default=FULL_PASS_EVERY,
        help="try all K dictionaries every N iterations (default "
        f"{FULL_PASS_EVERY}; 0: only when needed); the last pass is always full",
    )
    s.add_argument("--batch", type=int, default=4, help="data points per batch (memory bound)")
    s.add_argument("--seed", type=int, default=0,
                   help="seed of the data-point sample and the initial dictionaries (default 0)")
    s.add_argument("--crop", help="use only rows R0:R1 and columns C0:C1 of every BTF")
    s.add_argument("--checkpoint-dir",
                   help="save a checkpoint after each iteration here (default: OUTPUT.checkpoint "
                   "beside the model, removed once the model is written)")
    s.add_argument("--resume", action="store_true",
                   help="continue an interrupted run from its last finished iteration (same "
                   "inputs and options; an error names what differs)")
    add_cluster_options(s)
    s.add_argument("--json", action="store_true", help="print the training summary as JSON")
    s.set_defaults(func=run, checks={
        "dicts": integer(1, 65535, unit="dictionaries per ensemble"),
        "patch": integer(1, 4096, unit="texels"),
        "sample": number(0, 1, lo_open=True, unit="(fraction of each BTF's data points)"),
        "iters": integer(1, 10**6, unit="iterations"),
        "tol": number(0, unit="(relative objective decrease)"),
        "batch": integer(1, 4096, unit="data points per batch"),
        "candidates": integer(1, 65535, unit="dictionaries per point"),
        "full_pass_every": integer(0, 10**6, unit="iterations"),
        "seed": integer(0, 2**32 - 1),
    })  # fmt: skip

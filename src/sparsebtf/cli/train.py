"""``sparsebtf train``: learn a model (three dictionary ensembles) from BTFs (§3.2), in this
process or on a Dask cluster (``--workers`` / ``--scheduler``), saving a checkpoint after each
iteration (``--resume`` continues an interrupted run)."""

from __future__ import annotations

import argparse
import shutil
from pathlib import Path
from typing import Any

from ..codec.options import TrainOptions
from ..learning.ensemble import CANDIDATES, EXHAUSTIVE_MAX_ENTRIES, INITS
from ..points.preprocessing import STD_MODES
from ._args import (
    add_cluster_options,
    build_options,
    check_output_dir,
    check_output_file,
    check_resume,
    checkpoint_dir,
    cluster_options,
    log_offset,
    open_source,
    option_checks,
    parse_crop,
    resumable,
)
from ._output import print_json

__all__ = ["register"]

#: The library's defaults, which the flags show and take.
DEFAULTS = TrainOptions()
#: The numeric options and their flags: checked before the command by the library's table.
FLAGS = {"n_dictionaries": "--dicts", "patch": "--patch", "sample": "--sample",
         "max_iter": "--iters", "tol": "--tol", "candidates": "--candidates",
         "full_pass_every": "--full-pass-every", "batch_size": "--batch", "seed": "--seed"}


def run(args: argparse.Namespace) -> int:
    from ..codec.train import checkpoint_path
    from ..storage import save_model

    ck = checkpoint_dir(args)
    options = build_options(
        TrainOptions, FLAGS, n_dictionaries=args.dicts, tau_train=args.tau_train,
        tau_validation=args.tau_validation, init=args.init, patch=args.patch,
        sample=args.sample, max_iter=args.iters, tol=args.tol,
        std_mode=args.std_mode, log_offset=log_offset(args.log_offset),
        colour_mode=args.colour_mode, candidates=args.candidates,
        full_pass_every=args.full_pass_every, batch_size=args.batch, seed=args.seed,
        checkpoint_dir=str(ck), crop=parse_crop(args.crop),
    )  # fmt: skip
    check_output_file(args.output, args.btfs, kind="model")
    check_output_dir(str(ck), "--checkpoint-dir")
    # several patch sizes checkpoint by size, in subfolders (codec.train)
    check_resume(ck, args.resume, "**/" + Path(checkpoint_path(ck, "*")).name, "train")
    for s in args.btfs:  # one clear line for a bad input, before any work
        open_source(s, crop=args.crop)
    with resumable(ck):
        model = _train(args, options)
    save_model(model, args.output)
    if not args.checkpoint_dir:  # the default folder has served its purpose
        shutil.rmtree(ck, ignore_errors=True)
    _report(args, model)
    return 0


def _train(args: argparse.Namespace, options: TrainOptions) -> Any:
    from ..codec import train
    from ..execution import Execution

    return train(args.btfs, options=options, execution=Execution(**cluster_options(args)))


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


def _patches(text: str) -> int | str:
    """``--patch``: one size as an integer, several ("20,10,5") as given, for the library's
    one check (:class:`~sparsebtf.codec.options.TrainOptions`)."""
    try:
        return int(text)
    except ValueError:
        return text


def register(sub: Any) -> None:
    d = DEFAULTS
    s = sub.add_parser("train", help="learn a model (three dictionary ensembles) from BTFs")
    s.add_argument("btfs", nargs="+", metavar="BTF",
                   help="training BTFs: dense .h5, UBO2014 .btf, UBO2003 .zip or "
                   "synth:CLASS[:SIZE[:SEED]]")
    s.add_argument("-o", "--output", required=True, help="model file to write (.h5)")
    s.add_argument("--dicts", type=int, default=d.n_dictionaries,
                   help=f"dictionaries per ensemble K (default {d.n_dictionaries})")
    tau = ",".join(map(str, d.tau_train))
    s.add_argument("--tau-train", default=tau,
                   help=f"training sparsity per channel Y,U,V (default {tau}); several levels "
                   "split the dictionaries evenly over them, e.g. 64,8,8/256,32,32/885,64,64 "
                   "(each once; --dicts a multiple of their number); 'learn' (or learn:LEVELS) "
                   "chooses "
                   "each dictionary's level from the grid 64,8,8/256,32,32/885,64,64 by the "
                   "error on a held-out fifth of the training points (see docs/benchmarks.md)")
    s.add_argument("--tau-validation", metavar="LEVELS",
                   help="with --tau-train learn: the coding tau_t the validation error is "
                   "measured at, e.g. 885,64,64 or 326,40,40/885,64,64 (default: the grid's "
                   "levels); give the tau_t you will encode at")
    s.add_argument("--init", choices=INITS, default=d.init,
                   help=f"initial dictionaries (default {d.init}): points = the HOSVD of K random "
                   "training points, random, or preclustered (the HOSVD of K groups of points "
                   "with alike sparsity patterns under a DCT basis)")
    s.add_argument("--patch", type=_patches, default=d.patch, metavar="P[,P...]",
                   help=f"spatial patch size p (default {d.patch}); several that nest, such as "
                   "20,10,5 (largest first, each dividing the next larger), train one "
                   "ensemble per size into one model, for encode --adaptive-patches")
    s.add_argument("--sample", type=float, default=d.sample,
                   help=f"fraction of each BTF's data points used (default {d.sample:g})")
    s.add_argument("--iters", type=int, default=d.max_iter,
                   help=f"maximum iterations (default {d.max_iter})")
    s.add_argument("--tol", type=float, default=d.tol,
                   help=f"stop below this relative objective decrease (default {d.tol:g})")
    s.add_argument("--std-mode", choices=STD_MODES, default=d.std_mode,
                   help="standardisation: the release's shared mean/std, or per channel")
    s.add_argument("--log-offset", default=d.log_offset, metavar="auto|release|OFFSET",
                   help="the offset of ln(x + offset) of each training BTF: auto (default) = "
                   "1%% of its median positive value, at least 1e-5; release = 1e-5, the "
                   "authors'; or a number in [1e-5, 1e3]")
    s.add_argument("--colour-mode", action="store_true",
                   help="one 5D ensemble with colour as a mode (paper Table 6)")
    s.add_argument(
        "--candidates",
        type=int,
        default=d.candidates,
        help="dictionaries tried per point between full coding passes: its best ones at the "
        "last full pass (default: all K, the exhaustive trainer, when a full pass is cheap: "
        f"points x K x point size <= 2^{EXHAUSTIVE_MAX_ENTRIES.bit_length() - 1}, e.g. 29 "
        f"points of 10x10x151x151 at K = 8; else {CANDIDATES}; >= --dicts tries all K every "
        "iteration)",
    )
    s.add_argument("--full-pass-every", type=int, default=d.full_pass_every,
                   help=f"try all K dictionaries every N iterations (default "
                   f"{d.full_pass_every}; 0: only when needed); the last pass is always full")
    s.add_argument("--batch", type=int, default=d.batch_size,
                   help="data points per batch (memory bound)")
    s.add_argument("--seed", type=int, default=d.seed,
                   help=f"seed of the data-point sample and the initial dictionaries (default "
                   f"{d.seed})")
    s.add_argument("--crop", help="use only rows R0:R1 and columns C0:C1 of every BTF")
    s.add_argument("--checkpoint-dir",
                   help="save a checkpoint after each iteration here (default: OUTPUT.checkpoint "
                   "beside the model, removed once the model is written)")
    s.add_argument("--resume", action="store_true",
                   help="continue an interrupted run from its last finished iteration (same "
                   "inputs and options; an error names what differs)")
    add_cluster_options(s)
    s.add_argument("--json", action="store_true", help="print the training summary as JSON")
    # every option is checked by TrainOptions' table: the numbers before the command (and
    # again, with the rest, when the command builds the options: build_options)
    s.set_defaults(func=run, checks=option_checks(TrainOptions, FLAGS))

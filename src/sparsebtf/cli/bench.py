"""``sparsebtf bench``: reproduce the paper's comparative evaluation on our benchmark.

``bench quality`` fits the compared methods (``--methods``, ``--method``: SparseBTF, rate
control, [MHU19], PCA, the neural encodings, your own), codes the benchmark materials at
equal storage and writes ``results.json``, Markdown tables, plots and ``results.md`` (see
:mod:`sparsebtf.evaluation.runner`). ``bench report`` rewrites ``docs/results.md`` from a
finished run. Heavy modules are imported inside the commands.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

__all__ = ["register"]

PREVIOUS_HELP = ("an earlier run's results.json: write beside each verdict how it moved "
                 "(default with --docs: the run DOCS/results held before)")


def cmd_bench_quality(args: argparse.Namespace) -> int:
    from ..evaluation.benchmark_set import BenchConfig
    from ..evaluation.runner import run_quality
    from ._args import check_output_dir, cluster_options

    check_output_dir(args.out, "--out")
    check_output_dir(args.docs, "--docs")
    cfg = getattr(args, "config", None) or (
        BenchConfig.quick() if args.quick else
        BenchConfig.paper_crop() if args.paper_crop else BenchConfig())  # fmt: skip
    if args.source == "capture":
        cfg = cfg.captured()
    if args.test_classes is not None:
        from dataclasses import replace

        cfg = replace(cfg, test_classes=_test_classes(args.test_classes))
        cfg.test_set()  # an unknown class is one error line, before any material is made
    if args.log_offset is not None:
        from dataclasses import replace

        from ._args import log_offset

        cfg = replace(cfg, log_offset=log_offset(args.log_offset))
    if args.exhaustive:
        from dataclasses import replace

        cfg = replace(cfg, candidates=None)
    if args.objective is not None:
        from dataclasses import replace

        cfg = replace(cfg, objectives=_objectives(args.objective))
    if (device := _device(args)) is not None:
        from dataclasses import replace

        cfg = replace(cfg, torch_device=device)
    result = run_quality(Path(args.out), cfg, materials=args.materials or (), seed=args.seed,
                         previous=args.previous, methods=_methods(args), resume=args.resume,
                         **cluster_options(args))
    if args.docs:
        from ..evaluation.report import regenerate

        print(f"wrote {regenerate(args.out, args.docs, args.previous)}")
    if args.json:
        print(json.dumps(result["summary"], indent=2, default=str))
    return 0


def _objectives(text: str) -> tuple[str, ...]:
    """``--objective a,b,…``: coding objectives, each once, the first the run's own; an
    unknown or repeated one is one error line."""
    from ..errors import BTFInputError
    from ..learning.objective import check_objective

    names = [t.strip() for t in text.split(",") if t.strip()]
    if not names:
        raise BTFInputError("--objective: name at least one of log, linear, display")
    for n in names:
        try:
            check_objective(n)
        except BTFInputError as e:
            raise BTFInputError(f"--objective: {e}") from None
    if len(set(names)) != len(names):
        raise BTFInputError(f"--objective: {text!r} names an objective twice")
    return tuple(names)


def _test_classes(text: str) -> tuple[str, ...]:
    """``--test-classes a,b,…``: the test set's classes, each once."""
    from ..errors import BTFInputError

    names = [t.strip() for t in text.split(",") if t.strip()]
    if not names:
        raise BTFInputError("--test-classes: name at least one class")
    if len(set(names)) != len(names):
        raise BTFInputError(f"--test-classes: {text!r} names a class twice")
    return tuple(names)


def _device(args: argparse.Namespace) -> str | None:
    """``--device``, checked before any training (an unknown name, or CUDA that PyTorch does
    not find here, is one error line; with a remote scheduler only the name is checked: its
    workers are other machines). Without it, ``$SPARSEBTF_TORCH_DEVICE`` is checked the same
    way and stays each worker's own default (None)."""
    import os

    from ..errors import BTFInputError
    from ..execution import SCHEDULER_ENV

    remote = bool(args.scheduler or os.environ.get(SCHEDULER_ENV, "").strip())
    try:
        from ..evaluation.neural._torch import check_device, resolve_device
    except ImportError:
        if args.device is not None:
            raise BTFInputError("--device: PyTorch is not installed; the neural methods need "
                                "it (pip install 'sparsebtf[neural]')") from None
        return None
    if args.device is None:
        resolve_device(None, available=not remote)
        return None
    return check_device(args.device, "--device", available=not remote)


def _methods(args: argparse.Namespace) -> list[str]:
    """The methods of ``--methods`` (default: today's set, plus the neural ones when PyTorch
    imports; a note says when they were left out) and of every ``--method``, each resolved
    now so a bad name fails before any training."""
    import sys

    from ..evaluation.methods import method_class
    from ..evaluation.methods.selection import default_methods, parse_methods

    own = list(args.method or ())
    for spec in own:  # checked first: a bad one is the only line
        if ":" not in spec:
            from ..errors import BTFInputError

            raise BTFInputError(f"--method {spec}: expected package.module:Class (a registered "
                                "name goes in --methods)")
        method_class(spec)
    if args.methods is not None:
        names = parse_methods(args.methods)
    else:
        names = default_methods(note=lambda text: print(f"sparsebtf: note: {text}",
                                                        file=sys.stderr))  # fmt: skip
    names += own
    return names


def cmd_bench_report(args: argparse.Namespace) -> int:
    from ..evaluation.report import regenerate

    print(f"wrote {regenerate(args.run, args.docs, args.previous, args.captured)}")
    return 0


def _method_names() -> list[str]:
    from ..evaluation.methods import GROUPS, available_methods

    return [*available_methods(), *GROUPS]


def register(sub: Any) -> None:
    """Add the ``bench`` command (subcommands ``quality`` and ``report``)."""
    b = sub.add_parser("bench", help="quality benchmark: SparseBTF vs baselines at equal storage")
    bs = b.add_subparsers(dest="bench_command", required=True, metavar="BENCH")
    q = bs.add_parser(
        "quality",
        help="SparseBTF, rate control, [MHU19], PCA and the neural encodings at the paper's "
        "storage levels (Tables 2, 3, 5, Figure 3; about an hour on 2 cores without the "
        "neural methods, --quick under 10 minutes)",
    )
    q.add_argument("--out", default="bench-quality", help="output folder (default bench-quality)")
    size = q.add_mutually_exclusive_group()
    size.add_argument("--quick", action="store_true", help="small configuration (< 10 minutes)")
    size.add_argument("--paper-crop", action="store_true",
                      help="Table 3 alone at the paper's 100x100 test crops, one per class "
                      "(a side run: docs/paper-crop)")
    q.add_argument("--materials", nargs="+", metavar="BTF",
                   help="extra test BTFs (.btf, dense .h5, synth:...) at the same directions")
    q.add_argument("--seed", type=int, default=0, help="shifts every material and training seed")
    q.add_argument("--source", choices=["synth", "capture"], default="synth",
                   help="materials: synth (height-field ray-marcher, default) or capture "
                   "(Mitsuba 3 renders of the built-in samples of 'sparsebtf capture': true "
                   "black, high dynamic range; rendered once into the cache)")
    q.add_argument("--test-classes", metavar="A,B,...",
                   help="test only these of the source's classes (comma-separated; default "
                   "all); the training, Table-5 and true-black materials stay, so each test "
                   "material's rows are those of the whole run")
    q.add_argument("--log-offset", default=None, metavar="auto|release|OFFSET",
                   help="log offset of every SparseBTF encode (default auto; release = the "
                   "authors' 1e-5; see 'sparsebtf encode --help')")
    q.add_argument("--exhaustive", action="store_true",
                   help="every SparseBTF encode projects each data point on every dictionary "
                   "(the paper's rule; default: the encoder's screening, as 'sparsebtf "
                   "encode' does)")
    q.add_argument("--objective", metavar="log|linear|display[,...]",
                   help="coding objective of every SparseBTF encode (default log; see "
                   "'sparsebtf encode --help'); several, comma-separated, code the reference "
                   "and rate control under each (rows sparsebtf-<objective>, "
                   "rate-<objective>) and read the verdicts per objective")
    q.add_argument("--methods", metavar="A,B,...",
                   help="the compared methods, by name or group: "
                   + ", ".join(_method_names()) + " (default: sparsebtf, rate, per_channel, "
                   "raw, pca_log, pca_linear, and the neural rgjw20, rgjw20+ft, rjgw19, neumip "
                   "when PyTorch is installed). The reference, sparsebtf, is always run: its "
                   "per-material bytes set every other method's budgets")
    q.add_argument("--method", action="append", metavar="PACKAGE.MODULE:CLASS",
                   help="also compare your own sparsebtf.evaluation.methods.Method subclass "
                   "(repeatable; see docs/benchmarks.md, 'Your own method')")
    q.add_argument("--device", metavar="cpu|cuda|cuda:N|auto",
                   help="torch device of the neural methods' trainings and decodes (default "
                   "$SPARSEBTF_TORCH_DEVICE, else cpu; auto: cuda when PyTorch finds a GPU). "
                   "GPU runs are not bit-identical to CPU runs; every neural row records its "
                   "device (docs/neural-baselines.md, 'On a GPU')")
    q.add_argument("--docs", metavar="DIR",
                   help="also write DIR/results.md and DIR/results/*.png from this run")
    q.add_argument("--json", action="store_true", help="print the verdicts as JSON")
    q.add_argument("--previous", metavar="RESULTS_JSON", help=PREVIOUS_HELP)
    q.add_argument("--resume", action="store_true",
                   help="continue the interrupted run whose checkpoints OUT/partial holds "
                   "(fitted methods and finished materials are loaded, not recomputed; the "
                   "same settings are required)")
    from ._args import add_cluster_options, integer

    add_cluster_options(q)
    q.set_defaults(func=cmd_bench_quality, checks={"seed": integer(0, 2**31 - 1)})
    r = bs.add_parser("report", help="rewrite DOCS/results.md from a finished run's results.json")
    r.add_argument("run", help="folder of a 'bench quality' run (holds results.json)")
    r.add_argument("--docs", default="docs", help="docs folder (default docs)")
    r.add_argument("--previous", metavar="RESULTS_JSON", help=PREVIOUS_HELP)
    r.add_argument("--captured", metavar="RUN",
                   help="folder of a '--source capture' run whose verdicts go beside this "
                   "run's (default: DOCS/capture/results when it holds a results.json)")
    r.set_defaults(func=cmd_bench_report)

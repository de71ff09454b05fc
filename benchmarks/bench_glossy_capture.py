"""The glossy metals in the captured quality benchmark (issue 46): their verdicts per coding
objective without the whole eight-class run.

The quick captured configuration (``sparsebtf bench quality --quick --source capture``: K = 4
trained on seven captured materials of 20×20, the first seven classes of
:data:`~sparsebtf.evaluation.benchmark_set.CAPTURE_CLASSES`) tests only ``--classes`` (default:
``brushed``, ``copper-mirror``, ``copper-rough``, seed 12, 20×20). The training is the whole
run's, so each test material's rows are those the eight-class run gives it. Table 5 is coded on
``--table5`` (default ``brushed``, seed 5, 40×40) at level 32 alone (the paper's), in place of
the whole run's ``pebbles`` at every level; the true-black check (``metal``) is left out. Every
SparseBTF encode runs under each ``--objectives`` (default log, linear, display); the methods
are SparseBTF, rate control, [MHU19] on raw RGB (Table 2) and per-material PCA (Table 5). The
run folder holds results.json and results.md like any ``bench quality`` run (its "Command"
line does not know about the Table-5 and true-black changes).

    python benchmarks/bench_glossy_capture.py OUT [--classes brushed copper-mirror copper-rough]
        [--table5 brushed] [--objectives log linear display] [--log-offset auto|release|X]
"""

from __future__ import annotations

import argparse
from dataclasses import replace

from sparsebtf.evaluation.benchmark_set import CAPTURE_CLASSES, BenchConfig
from sparsebtf.evaluation.runner import run_quality
from sparsebtf.points.preprocessing import resolve_log_offset

GLOSSY = ("brushed", "copper-mirror", "copper-rough")
METHODS = ("sparsebtf", "rate", "raw", "pca")


def config(classes: tuple[str, ...] = GLOSSY, table5: str | None = "brushed",
           objectives: tuple[str, ...] = ("log", "linear", "display"),
           log_offset: str = "auto") -> BenchConfig:
    """The quick captured configuration testing ``classes``, Table 5 on ``table5`` (seed 5)
    at level 32, no true-black check, ``log_offset`` the rule of ln(x + offset) of training
    and coding ("auto", "release" or a number, as ``bench quality --log-offset``)."""
    return replace(BenchConfig.quick().captured(), test_classes=classes,
                   table5_materials=((table5, 5),) if table5 else (), table5_levels=(32,),
                   black_materials=(), objectives=objectives,
                   log_offset=log_offset)  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("out", help="run folder (results.json, results.md)")
    ap.add_argument("--classes", nargs="+", choices=CAPTURE_CLASSES, default=list(GLOSSY))
    ap.add_argument("--table5", choices=[*CAPTURE_CLASSES, "none"], default="brushed")
    ap.add_argument("--objectives", nargs="+", choices=("log", "linear", "display"),
                    default=["log", "linear", "display"])
    ap.add_argument("--log-offset", default="auto", metavar="auto|release|OFFSET")
    args = ap.parse_args()
    cfg = config(tuple(args.classes), None if args.table5 == "none" else args.table5,
                 tuple(args.objectives), resolve_log_offset(args.log_offset, "--log-offset"))
    print(f"training {cfg.train_set()}; test {cfg.test_set()}; Table 5 {cfg.table5_materials}",
          flush=True)
    run_quality(args.out, cfg, methods=list(METHODS))


if __name__ == "__main__":
    main()

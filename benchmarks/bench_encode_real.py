"""Encoding the real workload: the bundled (trained) model on a BTF-like material read from the
inputs a user has, with the time split by step beside the floor of its projections.

Inputs (``--inputs``, comma-separated): ``dense``, a synthetic material (``--material``,
default leather) rendered once into a dense float32 file (the ``synth:`` cache format, in
``--workdir``); ``lazy``, the 400×400-style lazy low-rank source of ``bench_encode.py`` (never
materialised); ``dfmf`` and ``fmf``, that source's factors written once as a UBO2014 ``.btf``
(DFMF binary16 per channel, FMF float shared; in ``--workdir``), read as a user's file is;
``--btf FILE`` adds a UBO2014 ``.btf`` of your own. Each input is encoded with the bundled
model at its defaults (τ = 885/64/64, ε = 1e-5, screening), as ``sparsebtf encode`` does,
then written to a coded file. Printed per input:

* the split: start-up (open, header), statistics (the whole pass, wall and CPU), coding
  (everything after it, wall and CPU: how many cores were busy), the coder's wait for data
  (reading + preprocessing not hidden behind the coding), writing; and the coding's CPU by
  kind of work, in thread CPU time: reading, preprocessing, energies, screening, exact
  projections, top-τ selection and the rest (each point's screening and projections run in
  one task, so only CPU time splits them);
* the floor of its projections: the exact projections made × 2·Σ_n m_n·∏m FLOPs, at this
  machine's float32 GEMM rate measured in the same run on the projection's own shape
  ((10·10·151) × 151 by 151 × 151, all cores) and on a large square GEMM; the ratio
  projections / floor is how far the projections are from the machine's rate.

    python benchmarks/bench_encode_real.py [--size 40] [--inputs dense,lazy] [--btf FILE]
        [--exhaustive] [--revision SRC] [--json]

``--revision SRC`` (a checkout's ``src`` folder, e.g. of f6f8cea, the revision before
screening: ``git worktree add /tmp/f6f8cea f6f8cea``) also times the whole command ``sparsebtf
encode FILE -o OUT`` on each file input (dense, ``.btf``) with this source tree and with SRC,
in turns (this, SRC, this, SRC), each the faster of its ``--revision-runs`` runs (default 2):
the ratio to that revision on the same input, measured in one run.

The default (40×40, 16 data points per input) runs in about two minutes on 2 cores; ``--size
100`` is the issue's 100×100 (a 2.8 GB dense file in ``--workdir``); ``--size 400`` the
UBO2014 size (44 GB dense: use ``--inputs lazy``). On a shared machine read the ratios, which
are measured within one run, not the seconds.
"""

from __future__ import annotations

import argparse
import contextlib
import math
import os
import subprocess
import sys
import tempfile
import threading
import time
import warnings
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np

from _common import best_of, gemm_gflops, machine, report


class Clock:
    """Seconds spent inside wrapped functions (wall time of the outermost calls on the calling
    thread, or another ``timer``), and calls counted."""

    def __init__(self) -> None:
        self.seconds: dict[str, float] = {}
        self.calls: dict[str, int] = {}
        self._lock = threading.Lock()

    def add(self, name: str, sec: float, calls: int = 1) -> None:
        with self._lock:
            self.seconds[name] = self.seconds.get(name, 0.0) + sec
            self.calls[name] = self.calls.get(name, 0) + calls

    def wrap(self, module: Any, attr: str, name: str,
             timer: Callable[[], float] = time.perf_counter,
             calls: Callable[[tuple[Any, ...]], int] = lambda args: 1) -> Callable[[], None]:
        """Time ``module.attr`` under ``name`` by ``timer``, each call counted as
        ``calls(args)``; returns what undoes it."""
        inner = getattr(module, attr)

        def timed(*args: Any, **kwargs: Any) -> Any:
            t = timer()
            try:
                return inner(*args, **kwargs)
            finally:
                self.add(name, timer() - t, calls(args))

        setattr(module, attr, timed)
        return lambda: setattr(module, attr, inner)

    def wrap_stream(self, module: Any, attr: str, name: str) -> Callable[[], None]:
        """A generator function: the time its consumer waits in next()."""
        inner = getattr(module, attr)

        def timed(*args: Any, **kwargs: Any) -> Iterator[Any]:
            it = inner(*args, **kwargs)
            while True:
                t = time.perf_counter()
                try:
                    item = next(it)
                except StopIteration:
                    self.add(name, time.perf_counter() - t)
                    return
                self.add(name, time.perf_counter() - t)
                yield item

        setattr(module, attr, timed)
        return lambda: setattr(module, attr, inner)


@contextlib.contextmanager
def instrumented(clock: Clock) -> Iterator[None]:
    """The encoder's steps timed: statistics and coding in wall and process CPU time; within
    the coding, which runs each point's screening and projections in one task on the worker
    threads, each kind of work in thread CPU time (robust to other jobs sharing the cores)."""
    import importlib

    enc = importlib.import_module("sparsebtf.codec.encode")  # the package exports encode()
    jobs = importlib.import_module("sparsebtf.codec.jobs")
    coding = importlib.import_module("sparsebtf.learning.coding")
    btf = importlib.import_module("sparsebtf.data.btf")
    pre = importlib.import_module("sparsebtf.points.preprocessing")
    cpu = time.thread_time

    undo = [
        clock.wrap(jobs, "_statistics", "statistics"),
        clock.wrap(jobs, "_statistics", "statistics cpu", timer=time.process_time),
        clock.wrap(enc, "sparse_code_batches", "coding"),
        clock.wrap_stream(enc, "stream_points", "waiting for data"),
        clock.wrap(btf.BTF, "patch", "reading cpu", timer=cpu),
        clock.wrap(pre.Preprocessor, "forward_into", "preprocessing cpu", timer=cpu),
        clock.wrap(coding, "sum_squares", "energies cpu", timer=cpu),
        # the exact projections counted
        clock.wrap(coding, "project_into", "projections made", timer=cpu,
                   calls=lambda args: args[0].shape[0]),
        clock.wrap(coding, "topk_abs", "selection cpu", timer=cpu),
        clock.wrap(coding._Screening, "keep", "screening cpu", timer=cpu),
    ]
    try:
        yield
    finally:
        for u in reversed(undo):
            u()


def projection_flops(sizes: list[int]) -> float:
    """FLOPs of one exact projection of a point of mode sizes ``sizes`` (square bases)."""
    return float(sum(2 * m * math.prod(sizes) for m in sizes))


def shaped_gemm_gflops(rows: int, inner: int) -> float:
    """Throughput (GFLOP/s, all cores) of the projection's own GEMM: (rows × inner) @
    (inner × inner) float32, as many side by side as there are cores (one per worker, the way
    the encoder runs its projections)."""
    from sparsebtf._threads import n_workers, parallel_map, single_threaded_blas

    rng = np.random.default_rng(0)
    k = n_workers()
    a = [rng.standard_normal((rows, inner)).astype(np.float32) for _ in range(k)]
    b = rng.standard_normal((inner, inner)).astype(np.float32)
    reps = 8

    def run() -> None:
        with single_threaded_blas():
            list(parallel_map(lambda i: [a[i] @ b for _ in range(reps)], range(k)))

    return 2 * rows * inner * inner * reps * k / best_of(run) / 1e9


def shaped_gemm_cpu_gflops(rows: int, inner: int, reps: int = 20) -> float:
    """The same GEMM's throughput per CPU second of one thread (its thread CPU time: what a
    core delivers while it runs it, whatever else shares the machine); best of 3."""
    from sparsebtf._threads import single_threaded_blas

    rng = np.random.default_rng(0)
    a = rng.standard_normal((rows, inner)).astype(np.float32)
    b = rng.standard_normal((inner, inner)).astype(np.float32)
    best = math.inf
    with single_threaded_blas():
        a @ b
        for _ in range(3):
            t = time.thread_time()
            for _ in range(reps):
                a @ b
            best = min(best, time.thread_time() - t)
    return 2 * rows * inner * inner * reps / best / 1e9


def ab_statistics(source: Any) -> dict[str, float]:
    """Wall and CPU seconds of the statistics as before (the "auto" offset's sample read
    first, then the sums) and now (one pass on the provisional offset), on ``source``."""
    from sparsebtf.open import open_btf
    from sparsebtf.points import statistics as st

    btf = open_btf(source) if isinstance(source, str) else source
    out = {}
    for name, fn in (
        ("two_passes", lambda: st.statistic_sums(btf, log_offset=st.choose_log_offset(btf))),
        ("one_pass", lambda: st.statistics_with_offset(btf, progress=False)),
    ):
        t, c = time.perf_counter(), time.process_time()
        fn()
        out[f"{name}_seconds"] = time.perf_counter() - t
        out[f"{name}_cpu_seconds"] = time.process_time() - c
    return out


def ab_projection(reps: int = 8) -> dict[str, float]:
    """CPU seconds of one exact projection of a 10×10×151×151 point and its top-885 selection,
    the way the coder made it before (:func:`project`: a fresh array per mode, a fresh |s|)
    and now (:func:`project_into` into the worker's buffers), one point per worker thread as
    the coder runs them, alternated ``reps`` times: the medians."""
    import statistics

    from sparsebtf._threads import n_workers, parallel_map, single_threaded_blas
    from sparsebtf.learning.codes import topk_abs
    from sparsebtf.learning.ensemble import random_orthonormal
    from sparsebtf.learning.tensor import project, project_into

    rng = np.random.default_rng(0)
    mats = [random_orthonormal(m, rng).astype(np.float32) for m in (10, 10, 151, 151)]
    k = n_workers()
    x = rng.standard_normal((k, 1, 10, 10, 151, 151)).astype(np.float32)
    bufs = [[np.empty(x[0].size, np.float32) for _ in range(3)] for _ in range(k)]

    def now(i: int) -> np.ndarray:
        b = bufs[i]  # as the coder's: one set per worker thread, reused
        return topk_abs(project_into(x[i], mats, b[:2]).reshape(-1), 885, scratch=b[2])

    fns = {"before": lambda i: topk_abs(project(x[i], mats).reshape(-1), 885), "now": now}
    cpu: dict[str, list[float]] = {name: [] for name in fns}
    with single_threaded_blas():
        for _ in range(reps):
            for name, fn in fns.items():
                c = time.process_time()
                list(parallel_map(lambda i, fn=fn: [fn(i) for _ in range(2)], range(k)))
                cpu[name].append((time.process_time() - c) / (2 * k))
    return {f"projection_{n}_cpu_seconds": statistics.median(v) for n, v in cpu.items()}


def encode_one(label: str, source: Any, workdir: Path, exhaustive: bool
               ) -> tuple[Any, dict[str, Any]]:  # fmt: skip
    from sparsebtf.codec import encode
    from sparsebtf.open import open_btf
    from sparsebtf.storage import save_coded
    from sparsebtf.storage.bundled import load_bundled

    clock = Clock()
    t0 = time.perf_counter()
    model = load_bundled()
    btf = open_btf(source) if isinstance(source, str) else source
    _ = btf.shape
    startup = time.perf_counter() - t0
    kw: dict[str, Any] = {"progress": False}
    if exhaustive:
        kw["candidates"] = None
    t, c = time.perf_counter(), time.process_time()
    with instrumented(clock):
        coded = encode(btf, model, **kw)
    wall, cpu = time.perf_counter() - t, time.process_time() - c
    out = workdir / f"{label}.coded.h5"
    t = time.perf_counter()
    save_coded(coded, out)
    writing = time.perf_counter() - t
    out.unlink()
    s = clock.seconds
    sizes = [int(d.shape[1]) for d in model.dictionaries["Y"]]
    stats, stats_cpu = s.get("statistics", 0.0), s.get("statistics cpu", 0.0)
    return coded, {
        "input": label,
        "points": coded.n_points,
        "startup_seconds": startup,
        "encode_seconds": wall,
        "encode_cpu_seconds": cpu,
        "statistics_seconds": stats,
        "statistics_cpu_seconds": stats_cpu,
        # everything after the statistics: reading, preprocessing, screening, projections
        "coding_seconds": wall - stats,
        "coding_cpu_seconds": cpu - stats_cpu,
        "coding_calls_seconds": s.get("coding", 0.0),
        "waiting_for_data_seconds": s.get("waiting for data", 0.0),
        "writing_seconds": writing,
        "projections_made": clock.calls.get("projections made", 0),
        **{f"{k}_cpu_seconds": s.get(f"{k.replace('_', ' ')} cpu", 0.0)
           for k in ("reading", "preprocessing", "energies", "screening", "selection")},
        "projections_cpu_seconds": s.get("projections made", 0.0),
        "projection_gflop": projection_flops(sizes) / 1e9,
        "nnz": coded.nnz(),
    }


def dense_source(material: str, size: int, workdir: Path) -> str:
    """The synthetic material as a dense float32 file in ``workdir`` (rendered once)."""
    from sparsebtf.data.synth import cached

    warnings.filterwarnings("ignore", message="caching synth")  # the file's size: expected
    return str(cached(material, size, "ubo2014", seed=0, cache_dir=workdir).path)


SRC = Path(__file__).resolve().parents[1] / "src"
#: ``sparsebtf`` from the source tree in argv[1], with the rest of argv as its arguments
CLI = ("import sys; sys.path.insert(0, sys.argv[1]); from sparsebtf.cli.main import main; "
       "sys.exit(main(sys.argv[2:]))")


def whole_commands(path: str, revision: str, workdir: Path, runs: int = 2) -> dict[str, Any]:
    """Wall seconds of ``sparsebtf encode PATH -o OUT`` (bundled model, defaults) from this
    source tree and from ``revision``'s, alternated, the faster of ``runs`` each."""
    times: dict[str, list[float]] = {"now": [], "revision": []}
    out = workdir / "whole-command.coded.h5"
    for _ in range(runs):
        for key, src in (("now", SRC), ("revision", Path(revision).resolve())):
            t = time.perf_counter()
            done = subprocess.run([sys.executable, "-c", CLI, str(src), "encode", path, "-o",
                                   str(out)], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                                  text=True, env={**os.environ, "SPARSEBTF_PROGRESS": "0"})
            if done.returncode:
                raise SystemExit(f"sparsebtf encode {path} from {src} failed: "
                                 f"{done.stderr.strip()[-500:]}")
            times[key].append(time.perf_counter() - t)
            out.unlink(missing_ok=True)
    now, rev = min(times["now"]), min(times["revision"])
    return {"revision": str(revision), "now_seconds": now, "revision_seconds": rev,
            "speedup": rev / now, "runs": times, "n_runs": runs}


def btf_source(size: int, rank: int, layout: str, workdir: Path) -> str:
    """The lazy source's factors (``bench_encode.lazy_source``) written once as a UBO2014
    ``.btf`` in ``workdir``: DFMF (binary16, per-channel factors, colour model 12: each
    channel in the log domain) or FMF (float, channel 0's spatial factor shared by the three
    channels, DRR: the log domain) of rank ``rank``; the reader decodes the factors per
    patch, as it does a user's file."""
    from bench_encode import lazy_source
    from sparsebtf.formats.ubo2014_write import write_ubo2014

    path = workdir / f"lazy{size}r{rank}-{layout.lower()}.btf"
    if path.exists():
        return str(path)
    src = lazy_source(size, rank)
    n_l, n_v = len(src.lights), len(src.views)
    # the file's angular rows are view·nL + light; the source's light·nV + view
    ang = [a.reshape(n_l, n_v, rank).transpose(1, 0, 2).reshape(n_l * n_v, rank)
           for a in src.angular]  # fmt: skip
    if layout == "DFMF":
        write_ubo2014(path, list(src.spatial), ang, size, size, src.lights, src.views,
                      layout="DFMF", dtype="half", rotations=False, color_model=12)
    else:  # FMF: one angular matrix, rows lv·3 + c
        write_ubo2014(path, src.spatial[0], np.stack(ang, axis=1).reshape(-1, rank), size,
                      size, src.lights, src.views, layout="FMF", dtype="float",
                      rotations=False, drr=True)  # fmt: skip
    return str(path)


def compare(screened: Any, full: Any, run: dict[str, Any], ex: dict[str, Any]
            ) -> dict[str, Any]:  # fmt: skip
    """The screened encode against the exhaustive one of the same input: points × channels
    whose dictionary differs, the relative change of the coder's summed error (mean squared
    residual of the standardised values, what the rule minimises), the coding's time."""
    changed = sum(int(np.sum(screened.codes[ch].membership != full.codes[ch].membership))
                  for ch in screened.codes)  # fmt: skip
    err_s = sum(float(np.sum(screened.codes[ch].errors)) for ch in screened.codes)
    err_f = sum(float(np.sum(full.codes[ch].errors)) for ch in full.codes)

    return {"point_channels": screened.n_points * len(screened.codes),
            "point_channels_changed": changed,
            "error_vs_exhaustive": err_s / err_f - 1 if err_f else 0.0,
            "coding_seconds": ex["coding_seconds"],
            "coding_speedup": ex["coding_seconds"] / run["coding_seconds"]}


STATS_AB = ("before (offset sample, then the sums) {two_passes_seconds:.2f} s wall, "
            "{two_passes_cpu_seconds:.2f} s CPU; now (one pass) {one_pass_seconds:.2f} s wall, "
            "{one_pass_cpu_seconds:.2f} s CPU")


REVISION = ("sparsebtf encode: {now_seconds:.1f} s now, {revision_seconds:.1f} s with "
            "{revision}: {speedup:.2f}x faster (the faster of {n_runs} run(s) each, in turns)")
EXHAUSTIVE = ("coding {coding_seconds:.1f} s exhaustive, {coding_speedup:.2f}x faster screened; "
              "{point_channels_changed} of {point_channels} point x channel changed "
              "dictionary; summed coding error {error_vs_exhaustive:+.4%}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", type=int, default=40, help="texels per side (default 40)")
    ap.add_argument("--material", default="leather")
    ap.add_argument("--inputs", default="dense,lazy",
                    help="dense, lazy, dfmf, fmf (comma-separated; dfmf and fmf: the lazy "
                    "source written as a UBO2014 .btf)")
    ap.add_argument("--btf", default=None, help="also this UBO2014 .btf file")
    ap.add_argument("--rank", type=int, default=100, help="the lazy source's rank")
    ap.add_argument("--workdir", default=None,
                    help="folder of the dense file (default: a temporary one, removed)")
    ap.add_argument("--exhaustive", action="store_true",
                    help="project every dictionary (the paper's rule), not the screened two")
    ap.add_argument("--ab", action="store_true",
                    help="also, in the same run, the statistics and one projection as the "
                    "code before issue 36 made them")
    ap.add_argument("--compare-exhaustive", action="store_true",
                    help="also encode each input with the exhaustive rule: the screening's "
                    "share of the coding, the points whose dictionary differs, the error")
    ap.add_argument("--revision", metavar="SRC", default=None,
                    help="also time the whole encode command of each file input with the "
                    "source tree SRC (e.g. a checkout of f6f8cea's src), in turns with this one")
    ap.add_argument("--revision-runs", type=int, default=2, metavar="N",
                    help="runs of each whole command for --revision (default 2; the faster "
                    "counts)")
    ap.add_argument("--json", action="store_true")
    a = ap.parse_args()
    # the rates before and after the encodes (the better of each): the other jobs' load varies
    shaped0, square0 = shaped_gemm_gflops(100 * 151, 151), gemm_gflops()
    with contextlib.ExitStack() as stack:
        workdir = Path(a.workdir) if a.workdir else Path(
            stack.enter_context(tempfile.TemporaryDirectory(prefix="bench-encode-real-")))
        workdir.mkdir(parents=True, exist_ok=True)
        inputs: list[tuple[str, Any]] = []
        for name in [x for x in a.inputs.split(",") if x]:
            if name == "dense":
                inputs.append((f"dense {a.material} {a.size}", dense_source(
                    a.material, a.size, workdir)))
            elif name == "lazy":
                from bench_encode import lazy_source

                inputs.append((f"lazy rank {a.rank} {a.size}", lazy_source(a.size, a.rank)))
            elif name in ("dfmf", "fmf"):
                inputs.append((f"btf {name.upper()} rank {a.rank} {a.size}",
                               btf_source(a.size, a.rank, name.upper(), workdir)))
            else:
                ap.error(f"--inputs: unknown input {name!r} (dense, lazy, dfmf, fmf)")
        if a.btf:
            inputs.append((f"btf {Path(a.btf).name}", str(Path(a.btf).absolute())))
        runs = []
        for label, src in inputs:
            coded, run = encode_one(label.replace(" ", "-"), src, workdir, a.exhaustive)
            runs.append(run)
            run["input"] = label
            if a.compare_exhaustive:
                full, ex = encode_one(label.replace(" ", "-"), src, workdir, True)
                run["exhaustive"] = compare(coded, full, run, ex)
            if a.ab:
                runs[-1]["ab_statistics"] = ab_statistics(src)
            if a.revision and isinstance(src, str):
                run["whole_commands"] = whole_commands(src, a.revision, workdir,
                                                       a.revision_runs)
    square = max(square0, gemm_gflops())
    shaped = max(shaped0, shaped_gemm_gflops(100 * 151, 151))
    per_core = shaped_gemm_cpu_gflops(100 * 151, 151)
    data = {"machine": machine(), "load_average": os.getloadavg(), "size": a.size,
            "rule": "exhaustive" if a.exhaustive else "screened (default)",
            "gemm_square_gflops": square, "gemm_projection_shape_gflops": shaped,
            "gemm_projection_shape_gflops_per_cpu_second": per_core, "runs": runs}
    if a.ab:
        data["ab_projection"] = ab_projection()
    rows: list[tuple[str, Any]] = [
        ("machine", f"{data['machine']['cpus']} cores, load average "
                    f"{data['load_average'][0]:.1f} (other jobs share them)"),
        ("GEMM rate", f"{shaped:.0f} GFLOP/s on the projection's shape (15100x151 @ 151x151, "
                      f"one per core); {square:.0f} GFLOP/s square 4096"),
        ("  per core", f"{per_core:.0f} GFLOP per CPU second of one thread (thread CPU "
                       "time: robust to the other jobs)"),
        ("model", f"bundled, default tau 885/64/64, {data['rule']}"),
    ]
    if a.ab:
        p = data["ab_projection"]
        floor = 1.4683844e9 / (per_core * 1e9)
        rows.append(("one projection (CPU)",
                     f"before {p['projection_before_cpu_seconds'] * 1e3:.1f} ms, now "
                     f"{p['projection_now_cpu_seconds'] * 1e3:.1f} ms, floor {floor * 1e3:.1f} ms"
                     f" ({floor / p['projection_now_cpu_seconds']:.0%} of the GEMM rate now, "
                     f"{floor / p['projection_before_cpu_seconds']:.0%} before)"))
    for r in runs:
        floor = r["projections_made"] * r["projection_gflop"] / shaped
        r["projections_floor_seconds"] = floor
        proj, screen = r["projections_cpu_seconds"], r["screening_cpu_seconds"]
        cpu_floor = r["projections_made"] * r["projection_gflop"] / per_core
        r["projections_cpu_floor_seconds"] = cpu_floor
        total = r["startup_seconds"] + r["encode_seconds"] + r["writing_seconds"]
        r["total_seconds"] = total
        coding, coding_cpu = r["coding_seconds"], r["coding_cpu_seconds"]
        kinds = ("reading", "preprocessing", "energies", "screening", "selection")
        rest = coding_cpu - proj - sum(r[f"{k}_cpu_seconds"] for k in kinds)
        n_cores = data["machine"]["cpus"]

        def share(x: float, of: float = coding_cpu) -> str:
            return f"{x:.2f} s ({x / max(of, 1e-9):.0%})"

        rows += [
            (r["input"], f"{r['points']} points, {total:.1f} s in all "
                         f"({total / r['points']:.3f} s per point)"),
            ("  start-up", f"{r['startup_seconds']:.2f} s"),
            ("  statistics", f"{r['statistics_seconds']:.2f} s wall, "
                             f"{r['statistics_cpu_seconds']:.2f} s CPU"),
            ("  coding", f"{coding:.2f} s wall, {coding_cpu:.2f} s CPU "
                         f"({coding_cpu / max(coding, 1e-9):.2f} of {n_cores} cores busy); "
                         f"waiting for data {r['waiting_for_data_seconds']:.2f} s"),
            ("  coding CPU: reading", share(r["reading_cpu_seconds"])),
            ("  coding CPU: preprocessing", share(r["preprocessing_cpu_seconds"])),
            ("  coding CPU: energies", share(r["energies_cpu_seconds"])),
            ("  coding CPU: screening", share(screen) + f"; {screen / max(proj + screen, 1e-9):.0%}"
                                                        " of screening + projections"),
            ("  coding CPU: projections", f"{share(proj)}: {r['projections_made']} made, "
                                          f"floor {cpu_floor:.2f} s at the per-core GEMM rate "
                                          f"({cpu_floor / max(proj, 1e-9):.0%} of the rate)"),
            ("  coding CPU: top-tau selection", share(r["selection_cpu_seconds"])),
            ("  coding CPU: the rest", share(rest) + " (choosing, bookkeeping, threads)"),
            ("  projections' floor (wall)", f"{floor:.2f} s at the shaped GEMM rate, all cores"),
            *([("  statistics A/B", STATS_AB.format(**r["ab_statistics"]))]
              if "ab_statistics" in r else []),
            *([("  vs exhaustive", EXHAUSTIVE.format(**r["exhaustive"]))]
              if "exhaustive" in r else []),
            *([("  whole command", REVISION.format(**r["whole_commands"]))]
              if "whole_commands" in r else []),
            ("  writing", f"{r['writing_seconds']:.2f} s"),
        ]
    report(rows, data, a.json)


if __name__ == "__main__":
    main()

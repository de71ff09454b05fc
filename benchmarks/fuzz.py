"""Fuzz every reader with thousands of mutated files, each case in its own process.

Each case is a seeded mutation of a small valid file made by our own writers
(:mod:`sparsebtf.fuzzing`: UBO2014 ``.btf``, UBO2003/ATRIUM ``.zip``, dense / model / coded
``.h5`` in schema 2 and schema 1, the authors' release files), run as a user would run it
(``sparsebtf info`` with its value scan; coded files are also decoded and loaded for the
renderer). Workers (``--jobs``, default 2) import everything once and fork one child per case,
which runs under an address-space cap (``--cap-gib`` above the worker's own size, default 1:
no allocation above 1 GiB) and a time limit (``--timeout``, default 60 s; libhdf5's own loops
are stopped by the package's 10 s watchdog first). Outcomes:

* **clean**: the reader refused the file with a project error (``sparsebtf: error: …``);
* **accepted**: the file was read (a mutation in unused bytes, or values that are still valid);
* **crash**: any other exception (a traceback), or a signal (segfault, bus error, abort);
* **hang**: the time limit killed the case;
* **kill**: the memory cap was hit (MemoryError, or killed by the kernel).

"max extra RSS" is the largest growth of a case's peak resident memory over its worker's,
including the HDF5 watchdog's forked walk (which has its own 512 MiB cap).

    python benchmarks/fuzz.py --cases 2500              # 15,000 cases, a few minutes
    python benchmarks/fuzz.py --cases 50 --readers coded dense
    python benchmarks/fuzz.py --replay coded 1234       # one case in process, with traceback

A defect prints its reader and seed; ``--replay`` reproduces it.

**Semantic mode** (``--semantic``): well-formed files that say impossible things. Each case
sets one field of a valid file of a kind (ubo2014, dense, model, coded, release, checkpoint)
to a boundary or impossible value (0, −1, huge, NaN, ±inf, tiny, a duplicated row, a
permutation, a sign flip, a scaling), keeping the file well-formed (a model's content hash and
a checkpoint's SHA-256 recomputed), runs what a user runs, and judges the outcome against the
format's rules (:func:`sparsebtf.fuzzing.run_semantic_case`): **rejected** (rules broken, one
project error), **correct** (rules hold, finite results, equal to the unmutated file's where
the field is unused), **silent wrong** (accepted although the rules are broken, or a changed
result from an unused field: must be 0), **false rejection** (refused although the rules
hold). Cases run in process (the byte-level mode covers crashes and hangs):

    python benchmarks/fuzz.py --semantic --cases 2000     # 12,000 cases
    python benchmarks/fuzz.py --semantic --replay coded 17
"""

from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import os
import resource
import select
import signal
import sys
import tempfile
import time
import traceback
from pathlib import Path
from typing import Any

from _common import machine
from sparsebtf.errors import SparseBTFError
from sparsebtf.fuzzing import (
    READERS,
    SEMANTIC_KINDS,
    SEMANTIC_OUTCOMES,
    build_corpus,
    build_semantic_corpus,
    exercise,
    run_semantic_case,
    sizes,
    write_case,
)

OUTCOMES = ("clean", "accepted", "crash", "hang", "kill")
_CORPUS: dict[str, list[Path]] = {}
_STATE: dict[str, Any] = {}


def _statm() -> tuple[int, int]:
    """(virtual size, resident size) of this process in bytes."""
    with open("/proc/self/statm") as fh:
        vm, rss = (int(v) for v in fh.read().split()[:2])
    page = os.sysconf("SC_PAGE_SIZE")
    return vm * page, rss * page


def _init(corpus: dict[str, list[Path]], corpus_dir: str, cap: int, timeout: float) -> None:
    """Worker start: everything imported and compiled once, so forked cases start warm."""
    _CORPUS.update(corpus)
    _STATE.update(corpus_dir=Path(corpus_dir), cap=cap, timeout=timeout,
                  work=Path(tempfile.mkdtemp(prefix="sparsebtf-fuzz-")))  # fmt: skip
    for reader, files in corpus.items():
        for f in files:
            exercise(reader, f, Path(corpus_dir))


def _child(reader: str, path: Path, w: int) -> None:  # pragma: no cover - runs forked
    vm, _ = _statm()
    limit = vm + _STATE["cap"]
    resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
    null = os.open(os.devnull, os.O_WRONLY)
    os.dup2(null, 1)
    os.dup2(null, 2)
    code, msg = 0, ""
    try:
        exercise(reader, path, _STATE["corpus_dir"])
    except SparseBTFError as e:  # also the HDF5 watchdog hitting its own 512 MiB cap
        code, msg = 10, str(e)
    except MemoryError:
        code, msg = 12, traceback.format_exc()
    except BaseException:
        code, msg = 11, traceback.format_exc()
    try:
        os.write(w, msg.encode("utf-8", "replace")[-20000:])
    finally:
        os._exit(code)


def run_one(reader: str, seed: int) -> dict[str, Any]:
    """Case ``seed`` of ``reader`` in a forked child: outcome, extra memory, seconds."""
    path = write_case(_CORPUS, reader, seed, _STATE["work"] / reader)
    _, base_rss = _statm()
    r, w = os.pipe()
    t0 = time.monotonic()
    pid = os.fork()
    if pid == 0:
        os.close(r)
        _child(reader, path, w)
    os.close(w)
    chunks, timed_out = [], False
    deadline = t0 + _STATE["timeout"]
    while True:
        left = deadline - time.monotonic()
        if left <= 0:
            timed_out = True
            os.kill(pid, signal.SIGKILL)
            break
        ready, _, _ = select.select([r], [], [], min(left, 1.0))
        if ready:
            data = os.read(r, 65536)
            if not data:
                break
            chunks.append(data)
    os.close(r)
    _, status, usage = os.wait4(pid, 0)
    seconds = time.monotonic() - t0
    detail = b"".join(chunks).decode("utf-8", "replace")
    if timed_out:
        outcome = "hang"
    elif os.WIFSIGNALED(status):
        sig = os.WTERMSIG(status)
        outcome = "kill" if sig == signal.SIGKILL else "crash"
        detail = f"signal {signal.Signals(sig).name}"
    else:
        outcome = {0: "accepted", 10: "clean", 12: "kill"}.get(os.WEXITSTATUS(status), "crash")
    extra = max(0, usage.ru_maxrss * 1024 - base_rss)
    return {"reader": reader, "seed": seed, "outcome": outcome, "extra_rss": extra,
            "seconds": seconds, "bytes": path.stat().st_size,
            "detail": detail if outcome in ("crash", "hang", "kill") else ""}  # fmt: skip


def _task(args: tuple[str, int, int]) -> list[dict[str, Any]]:
    reader, lo, hi = args
    return [run_one(reader, seed) for seed in range(lo, hi)]


def replay(reader: str, seed: int) -> int:
    """Run one case in this process and show what happened (a traceback for a defect)."""
    with tempfile.TemporaryDirectory() as d:
        corpus = build_corpus(Path(d) / "corpus")
        path = write_case(corpus, reader, seed, Path(d) / "case")
        print(f"case {reader} {seed}: {path.name}, {path.stat().st_size} bytes")
        try:
            exercise(reader, path, Path(d) / "corpus")
        except SparseBTFError as e:
            print(f"clean error: {e}")
            return 0
        print("accepted")
    return 0


def _semantic_task(args: tuple[str, int, int]) -> list[dict[str, Any]]:
    kind, lo, hi = args
    out = []
    for seed in range(lo, hi):
        t0 = time.perf_counter()
        try:
            res = run_semantic_case(_STATE["corpus"], kind, seed, _STATE["work"] / kind)
        except Exception:  # a defect: any exception but a project error
            res = {"kind": kind, "seed": seed, "case": "", "outcome": "crash",
                   "message": traceback.format_exc()[-400:]}  # fmt: skip
        res["seconds"] = time.perf_counter() - t0
        out.append(res)
    return out


def _tasks(kinds: Any, args: argparse.Namespace) -> list[tuple[str, int, int]]:
    """(kind, first seed, end seed) of every task: ``--chunk`` cases of one kind each."""
    end = args.first + args.cases
    return [(k, lo, min(lo + args.chunk, end))
            for lo in range(args.first, end, args.chunk) for k in kinds]  # fmt: skip


def semantic(args: argparse.Namespace) -> None:
    """The semantic mode: cases per kind in ``--jobs`` forked workers, one table."""
    kinds = [k for k in args.readers if k in SEMANTIC_KINDS] if args.readers_given else list(
        SEMANTIC_KINDS)  # fmt: skip
    os.environ.setdefault("SPARSEBTF_HDF5_GUARD", "0")  # in process: no watchdog fork per file
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="sparsebtf-semantic-") as d:
        _STATE.update(corpus=build_semantic_corpus(Path(d) / "corpus"), work=Path(d) / "cases")
        if args.replay:
            kind, seed = args.replay[0], int(args.replay[1])
            res = run_semantic_case(_STATE["corpus"], kind, seed, Path(d) / "replay")
            print(json.dumps(res, indent=2))
            return
        tasks = _tasks(kinds, args)
        results: list[dict[str, Any]] = []
        with mp.get_context("fork").Pool(args.jobs) as pool:
            for chunk in pool.imap_unordered(_semantic_task, tasks):
                results.extend(chunk)
                for res in chunk:
                    if res["outcome"] in ("silent_wrong", "crash", "false_rejection"):
                        print(f"{res['outcome'].upper()}: {res['kind']} seed {res['seed']} "
                              f"{res['case']} (--semantic --replay {res['kind']} {res['seed']})"
                              f" {res['message'][-300:]}", file=sys.stderr, flush=True)  # fmt: skip
    wall = time.perf_counter() - t0
    outcomes = (*SEMANTIC_OUTCOMES, "crash")
    table = {}
    for k in kinds:
        rows = [x for x in results if x["kind"] == k]
        table[k] = {"cases": len(rows), **{o: sum(x["outcome"] == o for x in rows)
                                           for o in outcomes},
                    "median_ms": sorted(x["seconds"] for x in rows)[len(rows) // 2] * 1000}
    if args.json:
        print(json.dumps({"table": table, "wall_seconds": wall, "jobs": args.jobs,
                          "machine": machine()}, indent=2))  # fmt: skip
        return
    print("| kind | cases | rejected | correct | silent wrong | false rejections | crashes | "
          "median time |")  # fmt: skip
    print("|" + "---|" * 8)
    for k, t in table.items():
        print(f"| {k} | {t['cases']} | {t['rejected']} | {t['correct']} | {t['silent_wrong']} | "
              f"{t['false_rejection']} | {t['crash']} | {t['median_ms']:.0f} ms |")
    total = sum(t["cases"] for t in table.values())
    silent = sum(t["silent_wrong"] for t in table.values())
    print(f"\n{total} cases in {wall:.0f} s on {args.jobs} workers; {silent} silent wrong outputs")


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--cases", type=int, default=2000, help="cases per reader (default 2000)")
    p.add_argument("--readers", nargs="+", choices=sorted({*READERS, *SEMANTIC_KINDS}),
                   default=list(READERS))
    p.add_argument("--first", type=int, default=0, help="first case seed (default 0)")
    p.add_argument("--jobs", type=int, default=2, help="worker processes (default 2)")
    p.add_argument("--timeout", type=float, default=60.0, help="seconds per case (default 60)")
    p.add_argument("--cap-gib", type=float, default=1.0,
                   help="address space a case may add, GiB (default 1)")
    p.add_argument("--chunk", type=int, default=25, help="cases per task (default 25)")
    p.add_argument("--replay", nargs=2, metavar=("READER", "SEED"))
    p.add_argument("--semantic", action="store_true",
                   help="semantic mode: well-formed files with impossible values (kinds: "
                   f"{', '.join(SEMANTIC_KINDS)})")
    p.add_argument("--json", action="store_true")
    args = p.parse_args()
    if args.semantic:
        args.readers_given = "--readers" in sys.argv
        semantic(args)
        return
    if args.replay:
        sys.exit(replay(args.replay[0], int(args.replay[1])))

    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="sparsebtf-corpus-") as d:
        corpus = build_corpus(d)
        tasks = _tasks(args.readers, args)
        cap = int(args.cap_gib * 2**30)
        ctx = mp.get_context("fork")
        results: list[dict[str, Any]] = []
        with ctx.Pool(args.jobs, _init, (corpus, d, cap, args.timeout)) as pool:
            for done, chunk in enumerate(pool.imap_unordered(_task, tasks), start=1):
                results.extend(chunk)
                for res in chunk:
                    if res["outcome"] in ("crash", "hang", "kill"):
                        print(f"DEFECT {res['outcome']}: {res['reader']} seed {res['seed']} "
                              f"(--replay {res['reader']} {res['seed']}): "
                              f"{res['detail'][-400:]}", file=sys.stderr, flush=True)  # fmt: skip
                if done % max(1, len(tasks) // 20) == 0:
                    el = time.perf_counter() - t0
                    print(f"[{done}/{len(tasks)} tasks, {el:.0f} s, ETA "
                          f"{el / done * (len(tasks) - done):.0f} s]", file=sys.stderr,
                          flush=True)  # fmt: skip
        seed_bytes = sizes(corpus)
    wall = time.perf_counter() - t0
    table = {}
    for r in args.readers:
        rows = [x for x in results if x["reader"] == r]
        table[r] = {
            "cases": len(rows),
            **{o: sum(x["outcome"] == o for x in rows) for o in OUTCOMES},
            "largest_input_bytes": max(x["bytes"] for x in rows),
            "seed_file_bytes": seed_bytes[r],
            "max_extra_rss_mib": max(x["extra_rss"] for x in rows) / 2**20,
            "over_1gib": sum(x["extra_rss"] > 2**30 for x in rows),
            "median_ms": sorted(x["seconds"] for x in rows)[len(rows) // 2] * 1000,
            "max_s": max(x["seconds"] for x in rows),
            "slowest_seed": max(rows, key=lambda x: x["seconds"])["seed"],
            "largest_rss_seed": max(rows, key=lambda x: x["extra_rss"])["seed"],
            "over_5s": [x["seed"] for x in rows if x["seconds"] > 5],
        }
    out = {"table": table, "wall_seconds": wall, "jobs": args.jobs, "timeout_s": args.timeout,
           "cap_gib": args.cap_gib, "machine": machine()}  # fmt: skip
    if args.json:
        print(json.dumps(out, indent=2))
        return
    head = ("| reader | cases | clean errors | accepted | crashes | hangs | kills | largest input "
            "| max extra RSS | median / max time |")  # fmt: skip
    print(head)
    print("|" + "---|" * 10)
    for r, t in table.items():
        print(f"| {r} | {t['cases']} | {t['clean']} | {t['accepted']} | {t['crash']} | "
              f"{t['hang']} | {t['kill']} | {t['largest_input_bytes']:,} B | "
              f"{t['max_extra_rss_mib']:.0f} MiB | {t['median_ms']:.0f} ms / {t['max_s']:.1f} s |")
    for r, t in table.items():
        print(f"{r}: slowest case {t['slowest_seed']}, largest memory case "
              f"{t['largest_rss_seed']}, {len(t['over_5s'])} cases over 5 s "
              f"{t['over_5s'][:10]} (replay: --replay {r} SEED)")
    total = sum(t["cases"] for t in table.values())
    bad = sum(t[o] for t in table.values() for o in ("crash", "hang", "kill"))
    print(f"\n{total} cases in {wall:.0f} s on {args.jobs} workers; {bad} crashes + hangs + kills;"
          f" cap {args.cap_gib:g} GiB above each worker, time limit {args.timeout:g} s per case")


if __name__ == "__main__":
    main()

"""Distributed encoding and training on Dask: the in-process default vs 1 and 2 local workers.

In one run: encoding throughput of the default (this process, one thread per core) and of a
``LocalCluster`` of 1 and 2 single-threaded worker processes on the same machine; parallel
efficiency T_1 / (n · T_n); the CPU time each run spent for the same work (what the Dask path
adds, a ratio that holds on a busy machine); per-task time; bytes moved (into the task graph,
between workers and to the client); the overhead of the Dask path for a small job (cluster
start-up, and a test-size encode on a running cluster against in process); and whether every
run gave the same codes, bit for bit.

    python benchmarks/bench_distributed.py [--part encode|train] [--size 40] [--dicts 8]
                                           [--workers 1,2] [--json]

The source is a dense file at UBO2014 angular resolution (size × size texels × 151 × 151),
written from the low-rank source of ``bench_encode.py``; the workers open it by path, as they
would from shared storage on a cluster. The model is K random orthonormal dictionaries per
channel (the encoder's cost does not depend on training). τ = (885, 64, 64), ε = 1e-5.

``--part train``: ``sparsebtf.codec.train`` on the same kind of source (every data point,
K = 8, τ_l = 256/32/32, ``--iters`` iterations with one candidate and the last pass full,
``--partition`` points per task) in process and on 1 and 2 worker processes: time, CPU time,
efficiency, per-task time (load, coding, cross products), bytes per iteration (dictionaries
out, sums back), whether every run gave the same dictionaries bit for bit, the small-job
overhead; then the single-core cost per paper-scale data point of each step, from which a
paper-scale training (2880 points per channel) on 16 and 64 machines of 2 cores is projected.
"""

from __future__ import annotations

import argparse
import os
import pickle
import statistics
import tempfile
import time
from collections import Counter
from typing import Any

import numpy as np

from _common import cpu_seconds, machine, peak_rss_bytes, report, small_job, task_seconds
from bench_encode import lazy_source, random_model
from sparsebtf.codec import encode_many
from sparsebtf.data.dense_file import write_dense
from sparsebtf.execution import executor

PARTS = ("encode", "train")


def _same_codes(a: Any, b: Any) -> bool:
    return all(
        np.array_equal(getattr(a.codes[ch], f), getattr(b.codes[ch], f))
        for ch in a.codes
        for f in ("membership", "counts", "values", "locations", "errors")
    )


def _encode(path: str, model: Any, a: argparse.Namespace, **where: Any) -> tuple[float, Any]:
    t = time.perf_counter()
    (coded,) = encode_many(
        [path], model, tau=a.tau, eps=1e-5, batch_size=a.batch, progress=False, **where
    )
    return time.perf_counter() - t, coded


def _import_codec() -> None:
    import sparsebtf.codec.jobs  # noqa: F401


def encoding_half(a: argparse.Namespace, tmp: str) -> tuple[list[tuple[str, Any]], dict]:
    path = f"{tmp}/source.h5"
    write_dense(path, lazy_source(a.size, a.rank))
    model = random_model(a.dicts)
    n_points = (a.size // 10) ** 2
    c0 = cpu_seconds()
    t0, ref = _encode(path, model, a)
    cpu0 = cpu_seconds() - c0
    moved = {
        "model_bytes": len(pickle.dumps(model)),
        "statistics_bytes": len(pickle.dumps(ref.stats)),
        "codes_bytes": len(pickle.dumps(ref.codes)),
    }
    runs: dict[str, Any] = {
        "in_process": {"seconds": t0, "points_per_s": n_points / t0, "cpu_seconds": cpu0}
    }
    small_btf, small_model = small_job()
    small_local = min(
        _encode_small(small_btf, small_model, {"client": None})[0] for _ in range(3)
    )
    small: dict[str, Any] = {"in_process_seconds": small_local}
    same = True
    for n in a.workers:
        from distributed import get_task_stream

        t = time.perf_counter()
        with executor(workers=n, dashboard=False, announce=False) as ex:
            client = ex.client  # type: ignore[attr-defined]
            client.run(_import_codec)  # start-up: every worker imports what tasks need
            start = time.perf_counter() - t
            cpu = sum(client.run(cpu_seconds).values()) + cpu_seconds()
            with get_task_stream(client=client) as ts:
                tn, coded = _encode(path, model, a, client=ex)
            cpu = sum(client.run(cpu_seconds).values()) + cpu_seconds() - cpu
            peak = max(client.run(peak_rss_bytes).values())
            if n == a.workers[0]:
                small["cluster_start_seconds"] = start
                small["on_cluster_seconds"] = min(
                    _encode_small(small_btf, small_model, {"client": ex})[0] for _ in range(3)
                )
        same &= _same_codes(ref, coded)
        ranges = task_seconds(ts.data, "_range")
        placed = Counter(r["worker"] for r in ts.data if "-_range-" in r["key"])
        sums = task_seconds(ts.data, "_sums")
        runs[f"workers_{n}"] = {
            "workers": n,
            "seconds": tn,
            "points_per_s": n_points / tn,
            "cpu_seconds": cpu,
            "worker_peak_rss_bytes": peak,
            "cluster_start_seconds": start,
            "tasks": len(ts.data),
            "range_tasks": len(ranges),
            "rangetask_seconds_median": statistics.median(ranges),
            "range_task_points": n_points / max(1, len(ranges)),
            "range_tasks_per_worker": sorted(placed.values()),
            "statistics_tasks": len(sums),
            "statisticstask_seconds_median": statistics.median(sums),
            # Dask's own transfer counters use sizeof() estimates, which miss our objects:
            # bytes are the pickled sizes, placed where the task stream says tasks ran.
            "bytes_between_workers": (len(placed) - 1) * (moved["model_bytes"]
                                                          + moved["statistics_bytes"]),
        }
    base = runs[f"workers_{a.workers[0]}"]
    for n in a.workers:
        r = runs[f"workers_{n}"]
        r["speedup_vs_first"] = base["seconds"] / r["seconds"]
        r["efficiency"] = base["seconds"] * a.workers[0] / (n * r["seconds"])
        r["vs_in_process"] = t0 / r["seconds"]
        # CPU spent for the same work: what the Dask path adds, whatever else the machine runs.
        r["cpu_vs_in_process"] = r["cpu_seconds"] / cpu0
    small["overhead_seconds"] = small["on_cluster_seconds"] - small["in_process_seconds"]
    data = {
        "size": a.size, "rank": a.rank, "dicts": a.dicts, "tau": a.tau, "points": n_points,
        "batch": a.batch, "runs": runs, "bytes": moved, "small_job": small,
        "identical_codes": same,
    }  # fmt: skip
    rows: list[tuple[str, Any]] = [
        ("source", f"{a.size}x{a.size}x151x151 dense file ({n_points} data points), K = "
                   f"{a.dicts}, tau = {a.tau}"),
        ("in process (default)", f"{t0:.1f} s, {n_points / t0:.2f} points/s, "
                                 f"CPU {cpu0:.1f} s"),
    ]
    for n in a.workers:
        r = runs[f"workers_{n}"]
        rows.append((
            f"{n} worker process{'es' if n > 1 else ''}",
            f"{r['seconds']:.1f} s, {r['points_per_s']:.2f} points/s, efficiency "
            f"{r['efficiency']:.2f}, {r['vs_in_process']:.2f}x in-process, CPU "
            f"{r['cpu_seconds']:.1f} s ({r['cpu_vs_in_process']:.2f}x in-process); "
            f"worker peak memory {r['worker_peak_rss_bytes'] / 2**30:.2f} GiB; "
            f"{r['range_tasks']} range tasks of {r['range_task_points']:.0f} points (median "
            f"{r['rangetask_seconds_median']:.2f} s, per worker "
            f"{'/'.join(map(str, r['range_tasks_per_worker']))}), {r['statistics_tasks']} "
            f"statistics tasks (median {r['statisticstask_seconds_median']:.2f} s); "
            f"between workers {r['bytes_between_workers'] / 2**20:.2f} MiB",
        ))  # fmt: skip
    rows += [
        ("bytes moved", f"out: model {moved['model_bytes'] / 2**20:.2f} MiB once, statistics "
                        f"{moved['statistics_bytes'] / 2**20:.2f} MiB per BTF, to each worker "
                        f"that uses them; back: codes {moved['codes_bytes'] / 2**20:.2f} MiB "
                        "per BTF (pickled sizes)"),
        ("small job (16x16, 13 dirs)",
         f"in process {small['in_process_seconds']:.2f} s, on a running cluster "
         f"{small['on_cluster_seconds']:.2f} s (+{small['overhead_seconds']:.2f} s), "
         f"cluster start {small['cluster_start_seconds']:.1f} s"),
        ("identical codes", "yes" if same else "NO"),
    ]  # fmt: skip
    return rows, data


def _encode_small(btf: Any, model: Any, where: dict[str, Any]) -> tuple[float, Any]:
    t = time.perf_counter()
    (coded,) = encode_many([btf], model, tau=(16, 4, 4), progress=False, **where)
    return time.perf_counter() - t, coded


def main() -> None:
    from bench_distributed_train import training_half

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--part", choices=PARTS, default="encode")
    ap.add_argument("--size", type=int, default=40)
    ap.add_argument("--rank", type=int, default=100)
    ap.add_argument("--dicts", type=int, default=8)
    ap.add_argument("--tau", default="885,64,64")
    ap.add_argument("--batch", type=int, default=2, help="data points per batch (default 2)")
    ap.add_argument("--workers", default="1,2", help="local cluster sizes, comma-separated")
    ap.add_argument("--iters", type=int, default=2, help="training iterations (--part train)")
    ap.add_argument("--partition", type=int, default=4,
                    help="training points per task (--part train; default 4)")
    ap.add_argument("--json", action="store_true")
    a = ap.parse_args()
    a.workers = [int(w) for w in a.workers.split(",")]
    with tempfile.TemporaryDirectory(prefix="bench-distributed-") as tmp:
        rows, data = (training_half if a.part == "train" else encoding_half)(a, tmp)
    data["machine"] = machine()
    data["load_average"] = os.getloadavg()
    rows.append(("load average (1, 5, 15 min)", ", ".join(f"{v:.1f}" for v in os.getloadavg())))
    report(rows, data, a.json)


if __name__ == "__main__":
    main()

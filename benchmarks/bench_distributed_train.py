"""The training half of ``bench_distributed.py`` (``--part train``); run that script."""

from __future__ import annotations

import argparse
import math
import os
import pickle
import statistics
import time
from typing import Any

import numpy as np

from _common import cpu_seconds, peak_rss_bytes, small_job, task_seconds
from bench_encode import lazy_source
from sparsebtf.codec import train
from sparsebtf.data.dense_file import DenseFileBTF, write_dense
from sparsebtf.execution import executor
from sparsebtf.learning.ensemble import ArraySource
from sparsebtf.learning.partitions import code_partition, cross_partition
from sparsebtf.learning.steps import pair_modes
from sparsebtf.points.sources import training_points

#: The paper's training (§3.2): 2880 points per channel, K = 8, 10×10×151×151, τ_l 256/32/32.
PAPER = {"points": 2880, "K": 8, "shape": (10, 10, 151, 151), "tau": (256, 32, 32)}
#: Points per task in the projection (the library's default partition).
PAPER_PARTITION = 8
#: Network assumed for the projection: 1 Gbit/s per machine.
BANDWIDTH = 125e6


def _import_training() -> None:
    import sparsebtf.codec.train  # noqa: F401


def _train(path: str, a: argparse.Namespace, **where: Any) -> tuple[float, Any]:
    t = time.perf_counter()
    model = train(
        [path], n_dictionaries=a.dicts, tau_train=a.tau_train, patch=10, sample=1.0,
        max_iter=a.iters, tol=0.0, candidates=1, full_pass_every=0, batch_size=a.batch,
        partition_size=a.partition, progress=False, **where,
    )  # fmt: skip
    return time.perf_counter() - t, model


def _same(a: Any, b: Any) -> bool:
    return all(
        np.array_equal(x, y)
        for ch in a.channels
        for x, y in zip(a.dictionaries[ch], b.dictionaries[ch], strict=True)
    )


def _step_costs(model: Any, path: str, a: argparse.Namespace) -> dict[str, float]:
    """Single-core seconds per 10×10×151×151 point: full coding (all K), partial coding (one
    candidate), cross products of one angular mode, for channel Y of the trained model."""
    old = os.environ.get("SPARSEBTF_THREADS")
    os.environ["SPARSEBTF_THREADS"] = "1"
    try:
        src = training_points([DenseFileBTF(path)], 10, 1.0, 0, progress=False).for_channel(0)
        n = min(a.partition, src.n_points)
        part = ArraySource(src.take(np.arange(n)))
        d = model.dictionaries["Y"]
        tau = a.tau_train[0]
        t = time.perf_counter()
        full = code_partition(part, d, tau, 0.0, np.float32, None, a.batch)
        t_full = (time.perf_counter() - t) / n
        cand = full.ranking[:, :1]
        t = time.perf_counter()
        code_partition(part, d, tau, 0.0, np.float32, cand, a.batch)
        t_partial = (time.perf_counter() - t) / n
        mode_b, mode_a = pair_modes(part.mode_sizes)
        other = next(m for m in range(4) if m not in (mode_b, mode_a))
        t = time.perf_counter()
        cross_partition(part, full.codes, d, other, np.float32, "codes", a.batch)
        t_cross = (time.perf_counter() - t) / n
    finally:
        if old is None:
            os.environ.pop("SPARSEBTF_THREADS")
        else:
            os.environ["SPARSEBTF_THREADS"] = old
    return {"full_coding": t_full, "partial_coding": t_partial, "cross_products": t_cross}


def _projection(cost: dict[str, float], bytes_: dict[str, int]) -> dict[str, Any]:
    """Paper-scale iteration times on M machines of 2 single-threaded workers: each pass is
    ceil(partitions / workers) rounds of one partition's work, plus its traffic at BANDWIDTH
    (dictionaries to every machine; sums up the tree, log2(partitions) hops of one Z)."""
    parts = math.ceil(PAPER["points"] / PAPER_PARTITION)
    out: dict[str, Any] = {"partitions_per_channel": parts}
    for machines in (1, 16, 64):
        w = 2 * machines
        rounds = math.ceil(parts / w)
        per_part = {k: v * PAPER_PARTITION for k, v in cost.items()}
        hops = math.ceil(math.log2(parts))
        comm_bcast = bytes_["dictionaries"] * machines / BANDWIDTH  # from one holder: worst
        comm_tree = hops * bytes_["cross_sum"] / BANDWIDTH
        comm_code = hops * bytes_["coding_sums"] / BANDWIDTH
        # An iteration: 2 cross-product passes (the angular modes) + a coding pass.
        cross = 2 * (rounds * per_part["cross_products"] + comm_bcast + comm_tree)
        partial = cross + rounds * per_part["partial_coding"] + comm_bcast + comm_code
        full = cross + rounds * per_part["full_coding"] + comm_bcast + comm_code
        out[f"machines_{machines}"] = {
            "workers": w, "rounds_per_pass": rounds,
            "iteration_partial_s": partial, "iteration_full_s": full,
            "communication_s": 3 * comm_bcast + 2 * comm_tree + comm_code,
            "efficiency": (parts * per_part["partial_coding"] / w) / (rounds * per_part[
                "partial_coding"]),
            # Loading each channel's points once (from storage as fast as this machine's).
            "load_s": rounds * per_part["load"],
            # Y, U, V one after the other; 10 iterations, the 10th and the first pass full.
            "training_10_iterations_h": 3 * (9 * partial + 2 * full + rounds * per_part[
                "load"]) / 3600,
            "points_per_worker_gib": PAPER["points"] * np.prod(PAPER["shape"]) * 4 / w / 2**30,
        }  # fmt: skip
    return out


def _t(seconds: float) -> str:
    """Seconds as s, min or h."""
    if seconds < 120:
        return f"{seconds:.1f} s"
    return f"{seconds / 60:.1f} min" if seconds < 7200 else f"{seconds / 3600:.2f} h"


def training_half(a: argparse.Namespace, tmp: str) -> tuple[list[tuple[str, Any]], dict]:
    a.tau_train = tuple(int(v) for v in a.tau.split(",")) if a.tau != "885,64,64" else (
        256, 32, 32)
    path = f"{tmp}/source.h5"
    write_dense(path, lazy_source(a.size, a.rank))
    n_points = (a.size // 10) ** 2
    c0 = cpu_seconds()
    t0, ref = _train(path, a)
    cpu0 = cpu_seconds() - c0
    runs: dict[str, Any] = {"in_process": {"seconds": t0, "cpu_seconds": cpu0,
                                           "points_per_s": 3 * a.iters * n_points / t0}}
    small_btf, _ = small_job()
    kw_small = dict(n_dictionaries=3, tau_train=(16, 4, 4), patch=4, sample=1.0, max_iter=2,
                    progress=False)  # fmt: skip
    t = time.perf_counter()
    small_ref = train([small_btf], **kw_small)
    small: dict[str, Any] = {"in_process_seconds": time.perf_counter() - t}
    same = True
    for n in a.workers:
        from distributed import get_task_stream

        t = time.perf_counter()
        with executor(workers=n, dashboard=False, announce=False) as ex:
            client = ex.client  # type: ignore[attr-defined]
            client.run(_import_training)
            start = time.perf_counter() - t
            cpu = sum(client.run(cpu_seconds).values()) + cpu_seconds()
            with get_task_stream(client=client) as ts:
                tn, model = _train(path, a, client=ex)
            cpu = sum(client.run(cpu_seconds).values()) + cpu_seconds() - cpu
            peak = max(client.run(peak_rss_bytes).values())
            if n == a.workers[0]:
                small["cluster_start_seconds"] = start
                t = time.perf_counter()
                small_model = train([small_btf], client=ex, **kw_small)
                small["on_cluster_seconds"] = time.perf_counter() - t
                same &= _same(small_ref, small_model)
        same &= _same(ref, model)
        tasks = {f: task_seconds(ts.data, f) for f in
                 ("load_partition", "code_partition", "cross_partition", "_add")}  # fmt: skip
        runs[f"workers_{n}"] = {
            "workers": n, "seconds": tn, "cpu_seconds": cpu,
            "points_per_s": 3 * a.iters * n_points / tn,
            "worker_peak_rss_bytes": peak, "cluster_start_seconds": start,
            "tasks": len(ts.data),
            **{f"{f}_tasks": len(v) for f, v in tasks.items()},
            **{f"{f}_median_s": statistics.median(v) if v else 0.0 for f, v in tasks.items()},
        }  # fmt: skip
    base = runs[f"workers_{a.workers[0]}"]
    for n in a.workers:
        r = runs[f"workers_{n}"]
        r["efficiency"] = base["seconds"] * a.workers[0] / (n * r["seconds"])
        r["vs_in_process"] = t0 / r["seconds"]
        r["cpu_vs_in_process"] = r["cpu_seconds"] / cpu0
    small["overhead_seconds"] = small["on_cluster_seconds"] - small["in_process_seconds"]
    d = ref.dictionaries["Y"]
    k = a.dicts
    m_b = d[pair_modes([u.shape[1] for u in d])[0]].shape[1]
    moved = {
        "dictionaries": len(pickle.dumps([u.copy() for u in d])),
        "cross_sum": k * 151 * 151 * 8,
        "coding_sums": k * (m_b * m_b + (10 * 10) ** 2) * 8,
        "rows_per_point": 8 + 8 + 8 * k,
    }
    parts = math.ceil(n_points / a.partition)
    per_iter = {
        "to_each_worker": 3 * moved["dictionaries"],
        "between_workers": (parts - 1) * (2 * moved["cross_sum"] + moved["coding_sums"]),
        "to_client": 2 * moved["cross_sum"] + moved["coding_sums"]
        + n_points * moved["rows_per_point"],
    }
    cost = _step_costs(ref, path, a)
    r1 = runs[f"workers_{a.workers[0]}"]
    cost["load"] = r1["load_partition_median_s"] / min(a.partition, n_points)
    proj = _projection(cost, moved)
    data = {"size": a.size, "points_per_channel": n_points, "dicts": k, "tau": a.tau_train,
            "iters": a.iters, "partition": a.partition, "runs": runs, "small_job": small,
            "bytes": moved, "bytes_per_iteration": per_iter, "single_core_seconds_per_point":
            cost, "paper_projection": proj, "identical_dictionaries": same}  # fmt: skip
    rows: list[tuple[str, Any]] = [
        ("source", f"{a.size}x{a.size}x151x151 dense file: {n_points} points per channel, "
                   f"K = {k}, tau_l = {a.tau_train}, {a.iters} iterations, {parts} partitions "
                   f"of {a.partition}"),
        ("in process (default)", f"{t0:.1f} s, CPU {cpu0:.1f} s"),
    ]  # fmt: skip
    for n in a.workers:
        r = runs[f"workers_{n}"]
        rows.append((
            f"{n} worker process{'es' if n > 1 else ''}",
            f"{r['seconds']:.1f} s, efficiency {r['efficiency']:.2f}, {r['vs_in_process']:.2f}x "
            f"in-process, CPU {r['cpu_seconds']:.1f} s ({r['cpu_vs_in_process']:.2f}x); worker "
            f"peak {r['worker_peak_rss_bytes'] / 2**30:.2f} GiB; median task: load "
            f"{r['load_partition_median_s']:.2f} s, coding {r['code_partition_median_s']:.2f} s,"
            f" cross products {r['cross_partition_median_s']:.2f} s, sum "
            f"{r['_add_median_s'] * 1e3:.1f} ms ({r['tasks']} tasks)",
        ))  # fmt: skip
    rows += [
        ("bytes per iteration", f"dictionaries {per_iter['to_each_worker'] / 2**20:.2f} MiB to "
         f"each worker (3 broadcasts of {moved['dictionaries'] / 2**20:.2f} MiB); sums "
         f"{per_iter['between_workers'] / 2**20:.2f} MiB between workers (tree of {parts}), "
         f"{per_iter['to_client'] / 2**20:.2f} MiB to the client"),
        ("single core per point", ", ".join(f"{k_} {v * 1e3:.1f} ms" for k_, v in cost.items())),
        ("small job (16x16, 13 dirs)",
         f"in process {small['in_process_seconds']:.2f} s, on a running cluster "
         f"{small['on_cluster_seconds']:.2f} s (+{small['overhead_seconds']:.2f} s), "
         f"cluster start {small['cluster_start_seconds']:.1f} s"),
        ("identical dictionaries", "yes" if same else "NO"),
    ]  # fmt: skip
    for machines in (1, 16, 64):
        p = proj[f"machines_{machines}"]
        rows.append((
            f"paper scale, {machines} x 2 cores",
            f"iteration {_t(p['iteration_partial_s'])} (partial) / "
            f"{_t(p['iteration_full_s'])} (full), of which network "
            f"{p['communication_s']:.1f} s; loading {_t(p['load_s'])} per channel; "
            f"10 iterations x 3 channels {_t(p['training_10_iterations_h'] * 3600)}; "
            f"points per worker "
            f"{p['points_per_worker_gib']:.2f} GiB; balance {p['efficiency']:.2f}",
        ))  # fmt: skip
    return rows, data

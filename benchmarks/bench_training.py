"""Training cost at 10×10×151×151: the fast trainer against the exhaustive one, in one run.

Both train the same Y-channel ensemble (K = 8, τ_l = 256) on the same data points for the
same number of iterations from the same initialisation:

* **exhaustive** — every coding pass projects every point on all K dictionaries, and every
  dictionary update forms the dense partial projection of every point for every mode
  (``candidates=K, update="projections"``: the trainer before the fast one);
* **fast** — the library defaults: partial coding passes on each point's best candidates
  of the last full pass, Z⁽ⁿ⁾ built from the τ_l coefficients, two modes free with the coding
  pass, the final memberships from a full pass;
* with ``--breakdown`` also the exhaustive coding with the fast update, to split the gain.

Reported: seconds per iteration per 1000 points, wall and CPU (the mean over the
iterations, the fast trainer's full passes included; the initialisation and first coding, the
same for both, are left out), their ratio, and the final objective of both with the relative
gap. The fast trainer runs first and last and its two figures are averaged, so a load that
drifts over the run (a shared machine) does not favour either side. The points
are the benchmark's synthetic materials (7 classes, 40×40 texels, UBO2014 directions,
cached), standardised log-YUV, channel Y. ``--memory`` instead measures the peak resident
memory of training channel Y from its staged file at several point counts (subprocesses;
``--memory-lazy 320`` adds all 1024 points of a lazy 320×320 low-rank source).

    python benchmarks/bench_training.py [--points 112] [--iters 10] [--json]
    python benchmarks/bench_training.py --memory [--memory-points 28 112] [--memory-lazy 320]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time

import numpy as np

from _common import machine, peak_rss_bytes, report
from sparsebtf.learning.ensemble import CANDIDATES, FULL_PASS_EVERY, DictionaryEnsemble

CLASSES = ("carpet", "fabric", "felt", "leather", "stone", "wallpaper", "wood")


def training_source(points: int, seed: int = 0):
    """``points`` standardised log-YUV training points of the benchmark materials (all
    three channels), as a streamed point source."""
    from sparsebtf.data.synth import cached
    from sparsebtf.points.sources import training_points

    btfs = [cached(c, 40, "ubo2014", 1) for c in CLASSES]
    per = 16  # 40×40 texels = 16 points of 10×10
    if not 1 <= points <= per * len(btfs):
        raise SystemExit(f"--points must be in [1, {per * len(btfs)}]")
    return training_points(btfs, 10, points / (per * len(btfs)), seed, progress=False)


def _fit(x: np.ndarray, iters: int, **kw) -> DictionaryEnsemble:
    return DictionaryEnsemble(
        n_dictionaries=8, tau=256, max_iter=iters, tol=0, random_state=0, progress=False, **kw
    ).fit(x)


def _timings(ens: DictionaryEnsemble, n_points: int) -> dict[str, float | None]:
    """Wall and CPU seconds per iteration per 1000 points, overall and by pass kind."""
    scale = 1000 / n_points
    kinds = np.array(ens.passes_[1:])
    out: dict[str, float | None] = {}
    for key, values in (("seconds", ens.iteration_seconds_),
                        ("cpu_seconds", ens.iteration_cpu_seconds_)):
        v = np.array(values) * scale
        out[f"{key}_per_iteration"] = float(v.mean())
        for kind in ("partial", "full"):
            sel = kinds == kind
            out[f"{key}_per_{kind}_iteration"] = float(v[sel].mean()) if sel.any() else None
    return out


def speed(a: argparse.Namespace) -> None:
    load_before = os.getloadavg()
    src = training_source(a.points).for_channel(0)
    x = np.concatenate([xb for _, xb in src.batches(8)])
    fast = dict(candidates=a.candidates, full_pass_every=a.full_pass_every)
    # The fast trainer runs first and last: the mean of the two cancels a load that drifts
    # linearly over the run (this machine is shared).
    runs = [("fast", fast), ("exhaustive", dict(candidates=8, update="projections"))]
    if a.breakdown:
        runs.append(("exhaustive coding, fast update", dict(candidates=8, update="codes")))
    runs.append(("fast (again)", fast))
    res = {}
    for name, kw in runs:
        t = time.perf_counter()
        ens = _fit(x, a.iters, **kw)
        res[name] = {
            "settings": kw,
            "seconds": time.perf_counter() - t,
            **_timings(ens, x.shape[0]),  # per 1000 points
            "objective": ens.objective_,
            "passes": ens.passes_,
            "membership_counts": ens.counts_.tolist(),
        }
    ex, fa, fb = res["exhaustive"], res["fast"], res["fast (again)"]
    speedup = {
        key: 2 * ex[f"{key}_per_iteration"] / (fa[f"{key}_per_iteration"]
                                              + fb[f"{key}_per_iteration"])
        for key in ("seconds", "cpu_seconds")
    }
    gap = fa["objective"][-1] / ex["objective"][-1] - 1
    data = {
        "machine": machine(),
        "load_average_before": load_before,
        "points": int(x.shape[0]),
        "iterations": a.iters,
        "runs": res,
        "speedup_per_iteration": speedup["seconds"],
        "speedup_per_iteration_cpu": speedup["cpu_seconds"],
        "objective_gap": gap,
        "load_average_after": os.getloadavg(),
    }
    rows = [("points x iterations", f"{x.shape[0]} x {a.iters} (channel Y, K = 8, tau_l = 256)")]
    for name, r in res.items():
        split = ""
        if r["seconds_per_partial_iteration"] is not None:
            split = (f" (partial {r['seconds_per_partial_iteration']:.1f}, full "
                     f"{r['seconds_per_full_iteration']:.1f})")
        rows.append((f"{name}: s / iteration / 1000 points, wall",
                     f"{r['seconds_per_iteration']:.1f}{split}"))
        rows.append((f"{name}: the same, CPU (2 threads)", f"{r['cpu_seconds_per_iteration']:.1f}"))
        rows.append((f"{name}: final objective", f"{r['objective'][-1]:.6g}"))
    rows += [
        ("fast settings", f"candidates = {a.candidates}, full pass every "
                          f"{a.full_pass_every or 'when needed'}; passes "
                          + "".join(p[0] for p in fa["passes"])),
        ("speed-up per iteration, wall", f"{speedup['seconds']:.2f}x (target >= 5x, aim 9x)"),
        ("speed-up per iteration, CPU", f"{speedup['cpu_seconds']:.2f}x"),
        ("objective gap (fast / exhaustive - 1)", f"{gap * 100:+.3f}% (target within 1%)"),
        ("paper scale (2880 points), fast",
         f"{fa['seconds_per_iteration'] * 2.88:.0f} s per iteration per channel"),
        ("load average before / after", "{:.1f} / {:.1f}".format(
            data["load_average_before"][0], data["load_average_after"][0])),
    ]  # fmt: skip
    report(rows, data, a.json)


def _memory_child(points: int, iters: int, lazy: int) -> None:
    """One measured run: stage channel Y of ``points`` points (or of every point of a lazy
    ``lazy``×``lazy`` low-rank source), train it, print the peak RSS (JSON)."""
    from sparsebtf.points.sources import channel_sources, training_points

    if lazy:
        from bench_encode import lazy_source

        src = training_points([lazy_source(lazy, 100)], 10, 1.0, 0, progress=False)
    else:
        src = training_source(points)
    t = time.perf_counter()
    with channel_sources(src, ("Y",), stage=True, batch_size=4) as source:
        staged = time.perf_counter() - t
        before = peak_rss_bytes()  # statistics and staging
        reset = _reset_peak_rss()
        held = _vm_bytes("VmRSS") if reset else None  # what the sources keep (chunk caches)
        ens = DictionaryEnsemble(
            n_dictionaries=8, tau=256, max_iter=iters, tol=0, random_state=0, progress=False
        ).fit(source("Y"))
        training = _vm_bytes("VmHWM") if reset else None
    print(json.dumps({
        "points": src.n_points, "source": f"lazy {lazy}x{lazy}" if lazy else "7 x 40x40 synth",
        "iterations": iters, "peak_rss_bytes": peak_rss_bytes(),
        "peak_rss_staging_bytes": before, "peak_rss_training_bytes": training,
        "rss_held_before_training_bytes": held,
        "added_by_training_bytes": None if held is None else training - held,
        "stage_seconds": staged, "fit_seconds": ens.fit_seconds_,
        "staged_bytes": src.n_bytes // 3,
    }))  # fmt: skip


def _reset_peak_rss() -> bool:
    """Reset this process's peak resident set to its current size (Linux clear_refs 5)."""
    try:
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")
        return True
    except OSError:
        return False


def _vm_bytes(field: str) -> int:
    """VmRSS (resident now) or VmHWM (peak since the last reset) of /proc/self/status."""
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith(f"{field}:"):
                return int(line.split()[1]) * 1024
    raise OSError(f"no {field} in /proc/self/status")


def memory(a: argparse.Namespace) -> None:
    out = []
    runs = [(n, 0) for n in a.memory_points] + [(0, s) for s in a.memory_lazy]
    for n, lazy in runs:
        cmd = [sys.executable, __file__, "--memory-child", str(n), "--memory-child-lazy",
               str(lazy), "--iters", str(a.memory_iters)]
        done = subprocess.run(cmd, capture_output=True, text=True, check=True)
        out.append(json.loads(done.stdout.strip().splitlines()[-1]))
    data = {"machine": machine(), "runs": out, "load_average": os.getloadavg()}
    def mib(v: int | None) -> str:
        return "?" if v is None else f"{v / 2**20:.0f} MiB"

    rows = [
        (f"{r['points']} points ({r['source']}), {r['iterations']} iteration(s)",
         f"training adds {mib(r['added_by_training_bytes'])} to the "
         f"{mib(r['rss_held_before_training_bytes'])} held before it (peak "
         f"{mib(r['peak_rss_training_bytes'])}); statistics and staging peak "
         f"{mib(r['peak_rss_staging_bytes'])}; staged channel Y "
         f"{r['staged_bytes'] / 2**30:.1f} GiB, fit {r['fit_seconds']:.0f} s")
        for r in out
    ]  # fmt: skip
    key = "added_by_training_bytes" if out[0]["added_by_training_bytes"] else "peak_rss_bytes"
    growth = out[-1][key] / out[0][key]
    rows.append(("memory added by training, last / first run",
                 f"{growth:.2f} for {out[-1]['points'] / out[0]['points']:.0f}x the points"))
    data["peak_ratio"] = growth
    report(rows, data, a.json)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--points", type=int, default=112)
    ap.add_argument("--iters", type=int, default=10)
    ap.add_argument("--candidates", type=int, default=CANDIDATES)
    ap.add_argument("--full-pass-every", type=int, default=FULL_PASS_EVERY)
    ap.add_argument("--breakdown", action="store_true",
                    help="also time the exhaustive coding with the fast update")
    ap.add_argument("--memory", action="store_true", help="peak memory at two point counts")
    ap.add_argument("--memory-points", type=int, nargs="*", default=[28, 112])
    ap.add_argument("--memory-lazy", type=int, nargs="*", default=[], metavar="SIZE",
                    help="also every point of a lazy SIZE x SIZE rank-100 source (320: 1024)")
    ap.add_argument("--memory-iters", type=int, default=1)
    ap.add_argument("--memory-child", type=int, help=argparse.SUPPRESS)
    ap.add_argument("--memory-child-lazy", type=int, default=0, help=argparse.SUPPRESS)
    ap.add_argument("--json", action="store_true")
    a = ap.parse_args()
    if a.memory_child is not None:
        _memory_child(a.memory_child, a.iters, a.memory_child_lazy)
    elif a.memory:
        memory(a)
    else:
        speed(a)


if __name__ == "__main__":
    main()

"""How long ``sparsebtf capture`` takes: a few views of each built-in sample, times the views.

Renders views 0, 75 and 150 (``--views`` of them, evenly spread) of a SIZE×SIZE capture at
UBO2014's 151 directions and ``--spp`` paths per texel, and prints per view the wall and CPU
time (all threads of this process), then both times 151 (a full capture renders each of the
151 views the same way: every texel, all 151 lights). CPU time is the steadier figure on a
shared machine; the LLVM backend runs on every core, so on idle cores the wall time is about
the CPU time over the number of cores.

    python benchmarks/bench_capture.py [--samples plane,woven] [--size 100] [--spp 16]
                                       [--views 3]
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np

from sparsebtf.data.capture import SAMPLES, capture_spec
from sparsebtf.data.capture.writer import _sample, render_block


def time_sample(name: str, size: int, spp: int, n_views: int) -> dict[str, float]:
    spec = capture_spec(name, size, "ubo2014", spp=spp)
    t = time.perf_counter()
    _sample(spec)  # load the scene and compile once, outside the timed views
    render_block(spec, 0)
    load = time.perf_counter() - t
    views = np.linspace(0, len(spec.directions) - 1, n_views).round().astype(int)
    cpu0, wall0 = time.process_time(), time.perf_counter()
    for v in views:
        render_block(spec, int(v))
    wall = (time.perf_counter() - wall0) / n_views
    cpu = (time.process_time() - cpu0) / n_views
    return {"load_s": load, "wall_per_view_s": wall, "cpu_per_view_s": cpu,
            "views": len(spec.directions)}  # fmt: skip


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--samples", default=",".join(SAMPLES))
    p.add_argument("--size", type=int, default=100)
    p.add_argument("--spp", type=int, default=16)
    p.add_argument("--views", type=int, default=3)
    a = p.parse_args()
    print(f"{a.size}x{a.size} texels, ubo2014 (151 x 151), {a.spp} spp, {os.cpu_count()} cores")
    for name in a.samples.split(","):
        r = time_sample(name, a.size, a.spp, a.views)
        n, wall, cpu = r["views"], r["wall_per_view_s"], r["cpu_per_view_s"]
        print(f"{name:8s} per view: wall {wall:6.1f} s, cpu {cpu:6.1f} s | {n} views: wall "
              f"{n * wall / 60:6.1f} min, cpu {n * cpu / 60:6.1f} min | load average "
              f"{os.getloadavg()[0]:.1f}", flush=True)  # fmt: skip


if __name__ == "__main__":
    main()

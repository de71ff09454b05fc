"""What the training variants beyond the paper cost (issue 34), at 10×10×151×151, channel Y.

Four fits of K = 8 dictionaries on the same data points, ``--iters`` iterations (tol 0):

* **reference**: one τ_l = 256, ``init="points"`` (the library default);
* **precluster**: ``init="preclustered"`` (DCT support k-medoids, per-group HOSVD: the
  initialisation's own seconds are reported apart);
* **multitau**: τ_l 256 and 885, four dictionaries each (two fits of K = 4);
* **learntau**: each dictionary's τ_l chosen from 64 / 256 / 885 on a validation fifth of the
  partitions (three fits of K = 8 on the rest, then the validation projections: reported
  apart).

Reported per variant: wall and CPU seconds of the whole fit, the final training objective
(for several levels: the mean of the levels'), and for pre-clustering the iterations it needs
to reach the reference's final objective. The points are all 25 points of each of the
benchmark's synthetic training materials (50×50 texels, UBO2014 directions, seed 1; cached by
``sparsebtf bench quality``), standardised log-YUV, channel Y; ``--points`` takes the first n.

``--variants`` runs only some (the reference always); ``--validation-taus`` gives the coding
τ_t learntau's validation error is measured at (default: its grid's levels; the bench's
levels 16–128 code Y at 308, 885, 2003, 4483).

    python benchmarks/bench_training_variants.py [--points 28] [--iters 4] [--json]
        [--variants precluster multitau learntau] [--validation-taus 308 885 2003 4483]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from _common import machine, report
from sparsebtf.learning.ensemble import DictionaryEnsemble
from sparsebtf.learning.init import preclustered_dictionaries
from sparsebtf.learning.partitions import ArraySource

CLASSES = ("carpet", "fabric", "felt", "leather", "stone", "wallpaper", "wood")


def points(n: int) -> np.ndarray:
    from sparsebtf.data.synth import cached
    from sparsebtf.points.sources import training_points

    btfs = [cached(c, 50, "ubo2014", 1) for c in CLASSES]
    src = training_points(btfs, 10, 1.0, 0, progress=False).for_channel(0)
    x = np.concatenate([xb for _, xb in src.batches(8)])
    return x[:n]


def fit(x: np.ndarray, iters: int, **kw) -> tuple[DictionaryEnsemble, float, float]:
    t, c = time.perf_counter(), time.process_time()
    ens = DictionaryEnsemble(n_dictionaries=8, max_iter=iters, tol=0, random_state=0,
                             progress=False, **kw).fit(x)  # fmt: skip
    return ens, time.perf_counter() - t, time.process_time() - c


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--points", type=int, default=28)
    p.add_argument("--iters", type=int, default=4)
    p.add_argument("--json", action="store_true")
    p.add_argument("--variants", nargs="+", default=["precluster", "multitau", "learntau"],
                   choices=["precluster", "multitau", "learntau"])
    p.add_argument("--validation-taus", nargs="+", type=int, default=None)
    a = p.parse_args()
    x = points(a.points)
    data: dict = {"machine": machine(), "points": int(x.shape[0]), "iters": a.iters}
    if "precluster" in a.variants:
        t, c = time.perf_counter(), time.process_time()
        preclustered_dictionaries(ArraySource(x), 8, 256, 0)
        data["precluster_init"] = {"seconds": time.perf_counter() - t,
                                   "cpu_seconds": time.process_time() - c}  # fmt: skip
    every = {
        "reference": dict(tau=256),
        "precluster": dict(tau=256, init="preclustered"),
        "multitau": dict(tau=[256, 885]),
        "learntau": dict(tau=[64, 256, 885], learn_tau=True,
                         validation_taus=a.validation_taus),
    }
    variants = {k: v for k, v in every.items() if k == "reference" or k in a.variants}
    fits = {}
    for name, kw in variants.items():
        ens, wall, cpu = fit(x, a.iters, **kw)
        fits[name] = ens
        data[name] = {"seconds": wall, "cpu_seconds": cpu, "objective": ens.objective_,
                      "taus": ens.taus_, "n_iter": ens.n_iter_}  # fmt: skip
        if name == "learntau":
            data[name]["validation"] = ens.validation_
    rows = [("points x iterations", f"{x.shape[0]} x {a.iters} (channel Y, K = 8)")]
    reach = None
    if "precluster" in fits:
        target = fits["reference"].objective_[-1]
        reach = next((i for i, v in enumerate(fits["precluster"].objective_) if v <= target),
                     None)  # fmt: skip
        data["precluster"]["iterations_to_reference_objective"] = reach
        rows.append(("precluster init alone", f"{data['precluster_init']['seconds']:.1f} s "
                     f"wall, {data['precluster_init']['cpu_seconds']:.1f} s CPU"))
    for name in variants:
        d = data[name]
        rows.append((name, f"{d['seconds']:.1f} s wall, {d['cpu_seconds']:.1f} s CPU, objective "
                     f"{d['objective'][0]:.5f} -> {d['objective'][-1]:.5f}, taus {d['taus']}"))
    if "precluster" in fits:
        rows.append(("precluster reaches the reference's objective at iteration", str(reach)))
    report(rows, data, a.json)


if __name__ == "__main__":
    main()

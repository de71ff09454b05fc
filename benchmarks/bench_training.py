"""Training cost: seconds per iteration per 1000 data points at 10×10×151×151.

One iteration is a coding pass (projection on K dictionaries + top-τ_l + membership) and one
Procrustes update per mode (a partial projection per point, SVDs of 151×151 sums). We time
iterations on a small set of points held in memory and scale to 1000 points (the cost is
linear in the number of points; the SVDs are a constant 8·4 small factorisations).

    python benchmarks/bench_training.py [--points 8] [--dicts 8] [--tau 256] [--json]
"""

from __future__ import annotations

import argparse

import numpy as np

from _common import machine, report
from sparsebtf.learning.ensemble import DictionaryEnsemble


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--points", type=int, default=8)
    ap.add_argument("--dicts", type=int, default=8)
    ap.add_argument("--tau", type=int, default=256)
    ap.add_argument("--iters", type=int, default=2)
    ap.add_argument("--json", action="store_true")
    a = ap.parse_args()
    rng = np.random.default_rng(0)
    # Smooth-ish random points: a sum of a few separable terms plus noise.
    shape = (10, 10, 151, 151)
    x = np.zeros((a.points, *shape), np.float32)
    for i in range(a.points):
        for _ in range(4):
            f = [rng.standard_normal(m) for m in shape]
            x[i] += np.einsum("a,b,c,d->abcd", *f).astype(np.float32)
        x[i] += 0.1 * rng.standard_normal(shape).astype(np.float32)
    kw = dict(n_dictionaries=a.dicts, tau=a.tau, tol=0, random_state=0)
    base = DictionaryEnsemble(max_iter=0, **kw).fit(x)  # initialisation + first coding
    ens = DictionaryEnsemble(max_iter=a.iters, **kw).fit(x)
    per_iter = (ens.fit_seconds_ - base.fit_seconds_) / a.iters
    per_1000 = per_iter / a.points * 1000
    data = {
        "machine": machine(),
        "points": a.points,
        "dicts": a.dicts,
        "tau": a.tau,
        "iterations": a.iters,
        "fit_seconds": ens.fit_seconds_,
        "seconds_per_iteration_per_1000_points": per_1000,
        "objective": ens.objective_,
    }
    report(
        [
            ("points x iterations", f"{a.points} x {a.iters} (K = {a.dicts}, tau_l = {a.tau})"),
            ("fit time", f"{ens.fit_seconds_:.1f} s"),
            ("s / iteration / 1000 points", f"{per_1000:.0f}"),
            (
                "paper scale (2880 points)",
                f"{per_1000 * 2.88 / 3600:.2f} h per iteration per channel",
            ),
        ],
        data,
        a.json,
    )


if __name__ == "__main__":
    main()

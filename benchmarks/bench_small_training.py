"""Small training problems: the candidate schedule against the exhaustive trainer.

Trains the same model (K = 8, τ_l = 256/32/32, 10×10 patches, every point, 10 iterations,
tol 1e-4) on 4 synthetic materials of SIZE×SIZE texels three times: with ``candidates=1``
(the candidate schedule: a partial pass on each point's best dictionary, full passes every
10 iterations and at the end), with ``candidates=8`` (exhaustive) and with the default
(``candidates=None``: exhaustive when a full pass is cheap, ``EXHAUSTIVE_MAX_ENTRIES``).
Prints, per material set, seed and size, the final objective gap of each against the
exhaustive one per channel (Y, U, V), and the seconds of each training.

    python benchmarks/bench_small_training.py [--sizes 20 40 60] [--directions tiny13]
"""

from __future__ import annotations

import argparse
import json
import time

from sparsebtf.codec import train
from sparsebtf.data.synth import cached

SETS = (("carpet", "fabric", "felt", "leather"), ("stone", "wallpaper", "wood", "metal"))


def _objectives(btfs: list, candidates: int | None) -> tuple[dict[str, float], float, int]:
    t = time.perf_counter()
    m = train(btfs, n_dictionaries=8, patch=10, sample=1.0, max_iter=10, progress=False,
              candidates=candidates)  # fmt: skip
    final = {ch: r["objective"][-1] for ch, r in m.training.items()}
    return final, time.perf_counter() - t, int(m.params["candidates"])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[20])
    ap.add_argument("--directions", default="tiny13", help="tiny13 or ubo2014")
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2])
    a = ap.parse_args()
    for size in a.sizes:
        for mats in SETS:
            for seed in a.seeds:
                btfs = [cached(c, size, a.directions, seed) for c in mats]
                ref, t_ref, _ = _objectives(btfs, 8)
                row = {"size": size, "points": (size // 10) ** 2 * len(mats),
                       "materials": "+".join(mats), "seed": seed,
                       "seconds_exhaustive": round(t_ref, 1)}  # fmt: skip
                for name, cand in (("candidates=1", 1), ("default", None)):
                    obj, secs, used = _objectives(btfs, cand)
                    row[f"gap_%_{name}"] = {ch: round(100 * (obj[ch] / ref[ch] - 1), 3)
                                            for ch in ref}  # fmt: skip
                    row[f"seconds_{name}"] = round(secs, 1)
                    if cand is None:
                        row["default_candidates"] = used
                print(json.dumps(row), flush=True)


if __name__ == "__main__":
    main()

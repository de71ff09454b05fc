"""Table 1's "fast local reconstruction": single BTF values decoded per second.

:func:`sparsebtf.evaluation.speed.decode_speed` on a SparseBTF reconstruction at UBO2014
angular resolution (151 × 151 directions, 10 × 10 patches, 40 × 40 texels, K = 8 random
orthonormal dictionaries per channel, τ = (885, 64, 64): the release's level; the cost of a
lookup depends on τ, K and the angular size, not on the values) and, for scale, an in-memory
dense table (10 × 10 texels, the same directions) read one value per call. Random queries on
the measured grid from a seeded generator, at batch 1 and at ``--batch``.

    python benchmarks/bench_decode_speed.py [--batch 65536] [--seconds 1] [--seed 0] [--json]
"""

from __future__ import annotations

import argparse

import numpy as np

from _common import machine, report, synthetic_coded
from sparsebtf.data.btf import ArrayBTF
from sparsebtf.evaluation.speed import decode_speed
from sparsebtf.runtime import coded_btf_view


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--batch", type=int, default=65536)
    ap.add_argument("--seconds", type=float, default=1.0, help="per rate (default 1)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    coded = synthetic_coded()
    rng = np.random.default_rng(args.seed)
    dense = ArrayBTF(rng.uniform(0, 1, (10, 10, 151, 151, 3)).astype(np.float32),
                     coded.lights, coded.views, name="dense")  # fmt: skip
    recs = {"SparseBTF (885/64/64)": coded_btf_view(coded), "dense table (read)": dense}
    res = decode_speed(recs, batch=args.batch, seconds=args.seconds, seed=args.seed)

    def rate(x: float | None) -> str:
        return "not batched" if x is None else f"{x:,.0f} /s"

    rows = []
    for label, r in res.items():
        rows += [
            (label, f"{r['path']}; backend {r['backend']} ({r['threads_of']} threads), "
                    f"{r['cpus']} cores"),
            ("  batch 1 (1 thread)", rate(r["queries_per_second_1"])),
            (f"  batch {args.batch} ({r['threads']} threads)",
             rate(r["queries_per_second_batch"])),
        ]  # fmt: skip
    report(rows, {"machine": machine(), "batch": args.batch, "seconds": args.seconds,
                  "seed": args.seed, "results": res}, args.json)  # fmt: skip


if __name__ == "__main__":
    main()

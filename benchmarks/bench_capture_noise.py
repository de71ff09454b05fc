"""How much of a capture is Monte Carlo noise: the noise variance of a ``sparsebtf capture``
file, measured against a **twin** — the same sample captured with another ``--noise-seed``,
whole or a window of it (``--crop``; :mod:`sparsebtf.data.capture.noise`). Over the twin's
window it reports the capture's σ² (linear RGB, per value: the unit of the benchmarks' MSE),
its share of the window's variance, the share of it in the values above 1 (the highlights),
and σ² at 16× the capture's spp.

    sparsebtf capture copper-mirror -o cm.h5 --size 40 --spp 4
    sparsebtf capture copper-mirror -o cm-twin.h5 --size 40 --spp 4 --noise-seed 1 --crop 0:20,0:20
    python benchmarks/bench_capture_noise.py cm.h5 cm-twin.h5 [--json]
"""

from __future__ import annotations

import argparse
from typing import Any

from _common import machine, report
from sparsebtf.data.capture.noise import noise_variance
from sparsebtf.errors import BTFInputError


def _rows(data: dict[str, Any]) -> list[tuple[str, str]]:
    return [(f"{r['scene']} ({r['spp']} spp)", (
        f"σ² {r['noise_variance']:.4g} per value ({r['noise_share_of_variance']:.1%} of the "
        f"variance {r['variance']:.4g}; {r['noise_share_above_1']:.1%} of it above 1); at "
        f"{16 * r['spp']} spp {r['noise_variance_at_16x_spp']:.3g} — twin {r['twin_spp']} spp "
        f"over rows {r['window'][0][0]}:{r['window'][0][1]}, cols "
        f"{r['window'][1][0]}:{r['window'][1][1]}, MSE {r['mse']:.4g}"))
        for r in data["runs"]]  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("capture")
    ap.add_argument("twins", nargs="+", help="captures of the same sample, other noise seed")
    ap.add_argument("--json", action="store_true")
    a = ap.parse_args()
    try:
        runs = [noise_variance(a.capture, t) for t in a.twins]
    except BTFInputError as e:
        raise SystemExit(f"bench_capture_noise: {e}") from None
    data = {"runs": runs, "machine": machine()}
    report(_rows(data), data, a.json)


if __name__ == "__main__":
    main()

"""How much of a capture is Monte Carlo noise: the noise variance of a ``sparsebtf capture``
file, measured against a **twin** — the same sample (scene, size, seed, directions, depth)
captured with another ``--noise-seed``, whole or a window of it (``--crop``).

Two independent estimates of the same values differ by their two noises,
E[(a − b)²] = σ²_a + σ²_b, and a path tracer's variance falls as 1/spp, so
σ²_a = MSE(a, b) · spp_b / (spp_a + spp_b). Over the twin's window it reports the capture's
σ² (linear RGB, per value: the unit of the benchmarks' MSE), its share of the window's variance,
the share of it in the values above 1 (the highlights), and σ² at 16× the capture's spp. A code
that errs by e against the capture errs by about e − σ² against the noiseless material where
it does not follow the noise: no representation should buy σ² back with bytes.

    sparsebtf capture copper-mirror -o cm.h5 --size 40 --spp 4
    sparsebtf capture copper-mirror -o cm-twin.h5 --size 40 --spp 4 --noise-seed 1 --crop 0:20,0:20
    python benchmarks/bench_capture_noise.py cm.h5 cm-twin.h5 [--json]
"""

from __future__ import annotations

import argparse
from typing import Any

import numpy as np

from _common import machine, report
from sparsebtf.errors import BTFInputError
from sparsebtf.open import open_btf

#: what must agree for two captures to be of one sample
SAMPLE_KEYS = ("scene", "scene_digest", "size", "seed", "directions", "max_depth",
               "capture_version")  # fmt: skip
#: rows read at once (memory: a band of the window, every direction)
ROWS = 4


def _capture(btf: Any, path: str) -> dict[str, Any]:
    a = dict(btf.attrs)
    if a.get("generator") != "sparsebtf.data.capture":
        raise BTFInputError(f"{path}: not a file of `sparsebtf capture`")
    a["noise"] = a.get("noise_seed", a["seed"])
    return a


def compare(capture: str, twin: str) -> dict[str, Any]:
    """σ² of ``capture`` over the window of ``twin`` (module docstring)."""
    with open_btf(capture) as a, open_btf(twin) as b:
        ka, kb = _capture(a, capture), _capture(b, twin)
        for k in SAMPLE_KEYS:
            if ka.get(k) != kb.get(k):
                raise BTFInputError(f"{twin}: not a twin of {capture}: {k} {kb.get(k)!r}, "
                                    f"expected {ka.get(k)!r}")  # fmt: skip
        if ka["noise"] == kb["noise"]:
            raise BTFInputError(f"{twin}: same noise seed as {capture} ({ka['noise']}): "
                                "capture the twin with another --noise-seed")  # fmt: skip
        (r0, r1), (c0, c1) = kb["rows"], kb["cols"]
        (ar, _), (ac, _) = ka["rows"], ka["cols"]
        if not (ka["rows"][0] <= r0 and r1 <= ka["rows"][1]
                and ka["cols"][0] <= c0 and c1 <= ka["cols"][1]):  # fmt: skip
            raise BTFInputError(f"{twin}: window rows {r0}:{r1}, cols {c0}:{c1} outside "
                                f"{capture}'s rows {ka['rows']}, cols {ka['cols']}")  # fmt: skip
        n = 0
        sums = dict.fromkeys(("d2", "d2_high", "a", "a2"), 0.0)
        for r in range(r0, r1, ROWS):
            rr = slice(r, min(r + ROWS, r1))
            va = np.asarray(a.region(slice(rr.start - ar, rr.stop - ar),
                                     slice(c0 - ac, c1 - ac)), dtype=np.float64)  # fmt: skip
            vb = np.asarray(b.region(slice(rr.start - r0, rr.stop - r0), slice(0, c1 - c0)),
                            dtype=np.float64)  # fmt: skip
            d2 = np.square(va - vb)
            sums["d2"] += float(d2.sum())
            sums["d2_high"] += float(d2[(va + vb) > 2].sum())
            sums["a"] += float(va.sum())
            sums["a2"] += float(np.square(va).sum())
            n += va.size
    mse = sums["d2"] / n
    share = ka["spp"] / (ka["spp"] + kb["spp"])  # σ²_b's part of E[(a − b)²] is spp_a/(…)
    sigma2 = mse * (1 - share)
    var = sums["a2"] / n - (sums["a"] / n) ** 2
    return {
        "capture": capture, "twin": twin, "scene": ka["scene"], "spp": ka["spp"],
        "twin_spp": kb["spp"], "window": [[r0, r1], [c0, c1]], "values": n, "mse": mse,
        "noise_variance": sigma2, "variance": var, "noise_share_of_variance": sigma2 / var,
        "noise_share_above_1": sums["d2_high"] / sums["d2"] if sums["d2"] else 0.0,
        "noise_variance_at_16x_spp": sigma2 / 16,
    }  # fmt: skip


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
        runs = [compare(a.capture, t) for t in a.twins]
    except BTFInputError as e:
        raise SystemExit(f"bench_capture_noise: {e}") from None
    data = {"runs": runs, "machine": machine()}
    report(_rows(data), data, a.json)


if __name__ == "__main__":
    main()

"""The Monte Carlo noise of a capture, measured against its **twin**: the same sample (scene,
size, seed, directions, depth) captured with another ``noise_seed``, whole or a window of it.

Two independent estimates of the same values differ by their two noises,
E[(a − b)²] = σ²_a + σ²_b, and a path tracer's variance falls as 1/spp, so
σ²_a = MSE(a, b) · spp_b / (spp_a + spp_b), per value in linear RGB (the unit of the
benchmarks' MSE). A code that errs by e against the capture errs by about e − σ² against the
noiseless material where it does not follow the noise: no representation should buy σ² back
with bytes (docs/benchmarks.md §17).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ...errors import BTFInputError
from ..dense_file import DenseFileBTF

__all__ = ["SAMPLE_KEYS", "noise_variance"]

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


def noise_variance(capture: str, twin: str) -> dict[str, Any]:
    """σ² of the capture file ``capture`` over the window of its twin ``twin`` (module
    docstring): ``noise_variance``, the window's ``variance`` and the twin's MSE, the share of
    the noise in values above 1, the window, both spp. Streams ``ROWS`` texel rows at a time."""
    with DenseFileBTF(capture) as a, DenseFileBTF(twin) as b:
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

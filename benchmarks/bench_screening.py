"""Screened vs exhaustive dictionary choice of the encoder (issue 22 item 1), on the bundled
``release`` model (K = 8, 10×10×151×151 data points, UBO2014 directions).

**Speed** (default): one synthetic material (``synth:leather``, seed 12, ``--size`` texels,
default 100×100: 100 data points), encoded at τ = (885, 64, 64), ε = 1e-5 with the
exhaustive rule (every point projected on every dictionary, the paper's) and with the
screening at each ``--candidates`` (the best N by a partial projection coded exactly, the
paper's rule among them). Per run: wall time, the speed-up over exhaustive, the linear-RGB MSE
against the material, and the data points (and point × channel pairs) whose dictionary
changed. The exact projections' FLOPs are counted too.

**Quality** (``--quality``): the quality benchmark's 14 unseen materials (seven classes, seeds
12 and 13, 30×30) and its Table-5 materials (carpet 12, felt 5, stone 5; ``--table5-size``,
default 100×100), coded at the storage levels 16/32/64/128 with the benchmark's fixed τ per
level (ε = 0, as ``bench_storage.py``), exhaustive and screened (each ``--candidates``), on the
bundled model (the benchmark's own trained model needs its hour of training). Per material and
level: both MSEs and their relative difference; the target is within 0.5 %.

    python benchmarks/bench_screening.py [--size 100] [--candidates 1 2 3] [--json]
    python benchmarks/bench_screening.py --quality [--candidates 1 2] [--table5-size 100]
                                         [--only unseen|table5] [--materials felt12 ...]
                                         [--json]
"""

from __future__ import annotations

import argparse
import sys
import time
from typing import Any
from unittest import mock

import numpy as np

from _common import machine, report
from bench_storage import LEVELS, level_taus
from sparsebtf.codec import encode_levels
from sparsebtf.data.synth import cached
from sparsebtf.evaluation.benchmark_set import BenchConfig
from sparsebtf.learning.coding import DEFAULT_CANDIDATES, partial_flops, screen_columns
from sparsebtf.metrics import compare
from sparsebtf.runtime import coded_btf_view
from sparsebtf.storage.bundled import load_bundled


def _mse(btf: Any, coded: Any) -> float:
    return float(compare(btf, coded_btf_view(coded), ssim_images=0, progress=False)["mse_rgb"])


def _timed_encode(btf: Any, model: Any, taus: list, eps: float, candidates: int | None
                  ) -> tuple[list, float, float]:  # fmt: skip
    """(coded BTFs, wall seconds, seconds spent choosing and coding: screening + projections
    + selection, i.e. in :func:`~sparsebtf.learning.coding.sparse_code_levels`; the rest is
    the statistics pass, reading and preprocessing, which the rule does not change)."""
    encode_mod = sys.modules["sparsebtf.codec.encode"]
    code = encode_mod.sparse_code_levels
    spent = [0.0]

    def timed(*args: Any, **kw: Any) -> Any:
        t0 = time.perf_counter()
        try:
            return code(*args, **kw)
        finally:
            spent[0] += time.perf_counter() - t0

    t = time.perf_counter()
    with mock.patch.object(encode_mod, "sparse_code_levels", timed):
        coded = encode_levels(btf, model, taus, eps=eps, allow_below_training=True,
                              candidates=candidates, progress=False)  # fmt: skip
    return coded, time.perf_counter() - t, spent[0]


def _changed(a: Any, b: Any) -> tuple[int, int]:
    """(data points whose dictionary differs in some channel, differing point × channel)."""
    diff = np.stack([a.codes[ch].membership != b.codes[ch].membership for ch in a.channels])
    return int(diff.any(axis=0).sum()), int(diff.sum())


def _neighbour_agreement(coded: Any) -> float:
    """Share of point × channel pairs (after the first point) whose dictionary is the previous
    point's: how good "the neighbouring patch's dictionary" would be as a sole guess."""
    same = [np.mean(c.membership[1:] == c.membership[:-1]) for c in coded.codes.values()]
    return float(np.mean(same))


def _flops(model: Any, n_points: int, candidates: int | None, tau: dict[str, int]) -> float:
    """FLOPs of the exact projections (Eq. 3, 2·Σ_n m_n·∏m) and of the screening's partial
    projections (:func:`~sparsebtf.learning.coding.partial_flops`, light and view columns from
    :func:`~sparsebtf.learning.coding.screen_columns` of each channel's τ)."""
    p1, p2, n_l, n_v = model.mode_sizes
    size = p1 * p2 * n_l * n_v
    exact = 2 * size * (p1 + p2 + n_l + n_v)
    total = 0.0
    for ch in model.channels:
        k = model.n_dictionaries(ch)
        if candidates is None:
            total += k * exact
            continue
        partial = partial_flops(model.mode_sizes, screen_columns(tau[ch], p1 * p2, n_l))
        total += k * partial + candidates * exact
    return n_points * total


def speed(size: int, candidates: list[int]) -> dict[str, Any]:
    model = load_bundled()
    btf = cached("leather", size, "ubo2014", 12)
    tau = (885, 64, 64)
    taus_c = dict(zip(model.channels, tau, strict=True))
    (ref,), t_ref, k_ref = _timed_encode(btf, model, [tau], 1e-5, None)
    mse_ref = _mse(btf, ref)
    runs = [{"rule": "exhaustive", "seconds": t_ref, "seconds_per_point": t_ref / ref.n_points,
             "coding_seconds": k_ref, "flops": _flops(model, ref.n_points, None, taus_c),
             "mse_rgb": mse_ref}]  # fmt: skip
    for c in candidates:
        (got,), t, k = _timed_encode(btf, model, [tau], 1e-5, c)
        mse = _mse(btf, got)
        points, pairs = _changed(ref, got)
        runs.append({
            "rule": f"screened, {c} candidates", "candidates": c, "seconds": t,
            "seconds_per_point": t / got.n_points, "speedup": t_ref / t,
            "coding_seconds": k, "coding_speedup": k_ref / k,
            "flops": _flops(model, got.n_points, c, taus_c), "mse_rgb": mse,
            "mse_vs_exhaustive": mse / mse_ref - 1,
            "points_changed": points, "point_channels_changed": pairs,
        })  # fmt: skip
    return {"material": f"synth:leather:{size}:12:ubo2014", "n_points": ref.n_points,
            "tau": list(tau), "eps": 1e-5, "runs": runs,
            "neighbour_agreement": _neighbour_agreement(ref)}  # fmt: skip


def quality(table5_size: int, candidates: list[int], groups: list[str] | None = None,
            names: list[str] | None = None) -> dict[str, Any]:  # fmt: skip
    model = load_bundled()
    cfg = BenchConfig()
    tau_l = tuple(model.params["tau_train"][ch] for ch in model.channels)
    taus = level_taus(LEVELS, tau_l)
    mats = [(c, s, cfg.test_size, "unseen") for c, s in cfg.test_set()]
    mats += [(c, s, table5_size, "table5") for c, s in cfg.table5_materials]
    mats = [m for m in mats if (groups is None or m[3] in groups)
            and (names is None or f"{m[0]}{m[1]}" in names)]  # fmt: skip
    rows = []
    for cls, seed, size, group in mats:
        print(f"quality: {cls}{seed} ({size}x{size})", file=sys.stderr, flush=True)
        btf = cached(cls, size, "ubo2014", seed)
        ex, t_ex, _ = _timed_encode(btf, model, [taus[lv] for lv in LEVELS], 0.0, None)
        m_ex = [_mse(btf, a) for a in ex]
        for c in candidates:
            sc, t_sc, _ = _timed_encode(btf, model, [taus[lv] for lv in LEVELS], 0.0, c)
            for lv, a, b, m in zip(LEVELS, ex, sc, m_ex, strict=True):
                m_sc = _mse(btf, b)
                rows.append({
                    "material": f"{cls}{seed}", "size": size, "group": group, "level": lv,
                    "tau": list(taus[lv]), "candidates": c, "mse_exhaustive": m,
                    "mse_screened": m_sc, "relative": m_sc / m - 1,
                    "points_changed": _changed(a, b)[0], "n_points": a.n_points,
                    "seconds_exhaustive": t_ex, "seconds_screened": t_sc,
                })  # fmt: skip
    summary = {}
    for c in candidates:
        mine = [r for r in rows if r["candidates"] == c]
        worst = max(mine, key=lambda r: r["relative"])
        summary[c] = {
            "worst_relative": worst["relative"],
            "worst": f"{worst['material']} level {worst['level']}",
            "mean_relative": float(np.mean([r["relative"] for r in mine])),
            "within_0_5_percent": all(r["relative"] <= 0.005 for r in mine),
            "speedup": sum(r["seconds_exhaustive"] for r in mine)
            / sum(r["seconds_screened"] for r in mine),
        }
    return {"model": "bundled release", "rows": rows, "summary": summary}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", type=int, default=100, help="texels per side (speed mode)")
    ap.add_argument("--candidates", type=int, nargs="+", default=None,
                    help=f"screened runs (default: 1 {DEFAULT_CANDIDATES} 3; --quality: "
                    f"{DEFAULT_CANDIDATES})")
    ap.add_argument("--quality", action="store_true")
    ap.add_argument("--table5-size", type=int, default=BenchConfig().table5_size)
    ap.add_argument("--only", nargs="+", choices=("unseen", "table5"), default=None,
                    help="--quality: only these material groups (default both)")
    ap.add_argument("--materials", nargs="+", metavar="NAME", default=None,
                    help="--quality: only these materials (class and seed, e.g. felt12)")
    ap.add_argument("--json", action="store_true")
    a = ap.parse_args()
    if a.candidates is None:
        a.candidates = [DEFAULT_CANDIDATES] if a.quality else [1, DEFAULT_CANDIDATES, 3]
    data: dict[str, Any] = {"machine": machine()}
    rows: list[tuple[str, Any]] = []
    if a.quality:
        q = quality(a.table5_size, a.candidates, a.only, a.materials)
        data["quality"] = q
        for r in q["rows"]:
            rows.append((f"{r['material']} ({r['size']}²) L{r['level']} c={r['candidates']}",
                         f"MSE exhaustive {r['mse_exhaustive'] * 1e4:.4f}e-4, screened "
                         f"{r['mse_screened'] * 1e4:.4f}e-4 ({r['relative']:+.3%}), "
                         f"{r['points_changed']}/{r['n_points']} points changed"))  # fmt: skip
        for c, sm in q["summary"].items():
            rows.append((f"{c} candidates", f"worst {sm['worst_relative']:+.3%} ({sm['worst']}), "
                         f"mean {sm['mean_relative']:+.3%}; within 0.5 %: "
                         f"{sm['within_0_5_percent']}; speed-up {sm['speedup']:.2f}x"))
    else:
        s = speed(a.size, a.candidates)
        data["speed"] = s
        rows.append(("material", f"{s['material']} ({s['n_points']} points), tau 885,64,64"))
        rows.append(("previous point's dictionary",
                     f"{s['neighbour_agreement']:.1%} of point x channel pairs (exhaustive)"))
        for r in s["runs"]:
            extra = ("" if r["rule"] == "exhaustive" else
                     f", speed-up {r['speedup']:.2f}x (coding {r['coding_speedup']:.2f}x), "
                     f"MSE {r['mse_vs_exhaustive']:+.3%}, "
                     f"{r['points_changed']} points ({r['point_channels_changed']} point x "
                     "channel) changed dictionary")  # fmt: skip
            rows.append((r["rule"], f"{r['seconds']:.1f} s ({r['seconds_per_point']:.3f} s/pt; "
                         f"coding {r['coding_seconds']:.1f} s), "
                         f"{r['flops'] / 1e12:.2f} TFLOP, MSE {r['mse_rgb']:.4g}{extra}"))
    report(rows, data, a.json)


if __name__ == "__main__":
    main()

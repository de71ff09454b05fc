"""The screening's partial projection, column split and margin against the exhaustive choice
(issue 36 item 3), on the bundled ``release`` model and the quality benchmark's unseen
materials (seven classes, seeds 12 and 13, 30×30: 9 data points each).

Each material's data points are taken as ``encode`` preprocesses them (per channel), then
projected exactly on all K = 8 dictionaries: the exhaustive choice per point, channel and
level. Against it, per **aspect** a (the light mode gets ⌈a·r⌉ columns, the view mode ⌈r/a⌉
of the square rule's r; a = 1 is the square window of before) and **margin** (a candidate after
the first is dropped when its partial error is more than the margin above the first's; inf:
never), :func:`~sparsebtf.learning.coding.screen_dictionaries`' rule (its own kernels) gives
the dictionaries each point keeps, in three workloads:

* ``levels``: the benchmark's four storage levels coded at once (fixed τ, ε = 0): a point
  keeps the union of its levels' candidates, as ``encode_levels`` does;
* ``single``: each of those levels coded alone (columns from its own τ);
* ``default``: τ = (885, 64, 64), ε = 1e-5, as ``sparsebtf encode`` codes.

Printed per (aspect, margin): the partial projection's MFLOP per dictionary (Y at its τ), the
choices whose exhaustive dictionary was not kept ("misses") and the worst relative error of
the best kept dictionary against the exhaustive one, and the exact projections per point and
channel (2 with no margin; fewer when a margin drops second candidates).

    python benchmarks/bench_screen_split.py [--aspects 1 2 3] [--margins 0.05 0.1 inf]
        [--materials felt12 wood12] [--json]

About 5 minutes on 2 cores for the default aspects and margins (the exhaustive projections: 8 ×
1.47 GFLOP per point and channel).
"""

from __future__ import annotations

import argparse
import math
import sys
from typing import Any
from unittest import mock

import numpy as np

from _common import machine, report
from bench_storage import LEVELS, level_taus
from sparsebtf.codec import encode_levels
from sparsebtf.data.synth import cached
from sparsebtf.evaluation.benchmark_set import BenchConfig
from sparsebtf.learning import coding
from sparsebtf.learning.codes import rule_keys
from sparsebtf.learning.tensor import project, sum_squares
from sparsebtf.storage.bundled import load_bundled

DEFAULT_TAU = (885, 64, 64)


def _points(btf: Any, model: Any) -> list[tuple[str, np.ndarray]]:
    """(channel, (B, 10, 10, 151, 151) float32) as the encoder codes them: each batch its
    coding call receives, recorded (the encode itself screens down to one candidate: its codes
    are not used)."""
    enc = sys.modules["sparsebtf.codec.encode"]
    seen: list[tuple[str, np.ndarray]] = []
    inner = enc.sparse_code_levels

    def spy(batch: np.ndarray, dictionaries: Any, *args: Any) -> Any:
        ch = next(c for c in model.channels if model.dictionaries[c] is dictionaries)
        seen.append((ch, np.array(batch, dtype=np.float32)))
        return inner(batch, dictionaries, *args)

    with mock.patch.object(enc, "sparse_code_levels", spy):
        encode_levels(btf, model, [DEFAULT_TAU], candidates=1, progress=False)
    return seen


def _exact(x: np.ndarray, dicts: list[np.ndarray], top: int) -> np.ndarray:
    """(K, top) the exact projections' largest squares, decreasing."""
    sq = np.stack([project(x[None], [d[k] for d in dicts]).reshape(-1).astype(np.float64) ** 2
                   for k in range(dicts[0].shape[0])])  # fmt: skip
    return coding._top_squares(sq, top)


def _workloads(model: Any) -> dict[str, tuple[list[list[int]], float]]:
    """Per workload: its encodes (each a list of per-channel-ordered τ tuples) and ε."""
    tau_l = tuple(model.params["tau_train"][ch] for ch in model.channels)
    taus = level_taus(LEVELS, tau_l)
    levels = [list(taus[lv]) for lv in LEVELS]
    return {"levels": ([levels], 0.0), "single": ([[t] for t in levels], 0.0),
            "default": ([[list(DEFAULT_TAU)]], 1e-5)}  # fmt: skip


def _misses(kept: np.ndarray, truth: list[tuple[np.ndarray, np.ndarray]], win: list[int]
            ) -> list[float]:  # fmt: skip
    """Per level whose exhaustive dictionary ``win`` was not ``kept``: the relative error of
    the best kept one (the coding rule among them) against it."""
    ks = np.flatnonzero(kept)
    out = []
    for (n, e), w in zip(truth, win, strict=True):
        got = int(ks[np.lexsort((e[ks], n[ks]))[0]])
        if got != w:
            out.append(e[got] / max(e[w], 1e-300) - 1)
    return out


def split(aspects: list[float], margins: list[float], names: list[str] | None
          ) -> dict[str, Any]:  # fmt: skip
    model = load_bundled()
    cfg = BenchConfig()
    mats = [(c, s) for c, s in cfg.test_set() if names is None or f"{c}{s}" in names]
    work = _workloads(model)
    tmax = {ch: max(max(t[i] for enc in w for t in enc) for w, _ in work.values())
            for i, ch in enumerate(model.channels)}  # fmt: skip
    # per (aspect, margin, workload): misses, worst relative error, kept, point × channel, choices
    tally: dict[tuple[float, float, str], list[float]] = {}
    for cls, seed in mats:
        print(f"split: {cls}{seed}", file=sys.stderr, flush=True)
        btf = cached(cls, cfg.test_size, "ubo2014", seed)
        for ch, batch in _points(btf, model):
            c = model.channels.index(ch)
            dicts = [np.asarray(d, np.float32) for d in model.dictionaries[ch]]
            p1, p2, n_l = batch.shape[1:4]
            size = int(np.prod(batch.shape[1:]))
            for x in batch:
                energy = float(sum_squares(x.reshape(1, -1))[0])
                exact = _exact(x, dicts, tmax[ch])
                for name, (encodes, eps) in work.items():
                    for levels in (sorted({min(t[c], size) for t in enc}) for enc in encodes):
                        truth = [rule_keys(exact, energy, size, t, eps) for t in levels]
                        win = [int(np.lexsort((e, n))[0]) for n, e in truth]
                        for a in aspects:
                            cols = coding.screen_columns(levels[-1], p1 * p2, n_l, aspect=a)
                            part = coding._partial_top(x, dicts, cols, levels[-1])
                            for m in margins:
                                kept = coding._kept(part, energy, size, levels, eps, 2, m)
                                missed = _misses(kept, truth, win)
                                t = tally.setdefault((a, m, name), [0, 0.0, 0, 0, 0])
                                t[0] += len(missed)
                                t[1] = max([t[1], *missed])
                                t[2] += int(kept.sum())
                                t[3] += 1
                                t[4] += len(levels)
    shape = model.mode_sizes
    rows = []
    for (a, m, name), (miss, worst, kept, n, choices) in sorted(tally.items()):
        cols = coding.screen_columns(DEFAULT_TAU[0], shape[0] * shape[1], shape[2], aspect=a)
        rows.append({"aspect": a, "margin": m, "workload": name, "columns_at_885": list(cols),
                     "mflop_per_dictionary": coding.partial_flops(shape, cols) / 1e6,
                     "misses": miss, "choices": choices, "worst_relative": worst,
                     "projections_per_point_channel": kept / n})  # fmt: skip
    return {"model": "bundled release", "materials": [f"{c}{s}" for c, s in mats],
            "rows": rows}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--aspects", type=float, nargs="+", default=[1.0, 2.0, 3.0])
    ap.add_argument("--margins", type=float, nargs="+", default=[0.05, 0.1, 0.2, math.inf])
    ap.add_argument("--materials", nargs="+", metavar="NAME", default=None,
                    help="only these unseen materials (class and seed, e.g. felt12)")
    ap.add_argument("--json", action="store_true")
    a = ap.parse_args()
    data = {"machine": machine(), **split(a.aspects, a.margins, a.materials)}
    rows: list[tuple[str, Any]] = [("materials", ", ".join(data["materials"]))]
    for r in data["rows"]:
        rows.append((f"aspect {r['aspect']:g} ({r['columns_at_885'][0]}x"
                     f"{r['columns_at_885'][1]} at 885), margin {r['margin']:g}, {r['workload']}",
                     f"{r['mflop_per_dictionary']:.0f} MFLOP/dict; misses {r['misses']} of "
                     f"{r['choices']} (worst {r['worst_relative']:+.2%}); "
                     f"{r['projections_per_point_channel']:.2f} projections per point x "
                     "channel"))  # fmt: skip
    report(rows, data, a.json)


if __name__ == "__main__":
    main()

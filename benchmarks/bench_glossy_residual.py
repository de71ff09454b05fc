"""Where a glossy metal's error lives (issue 46, item 2): the linear-RGB error of the bundled
``release`` model per level, split between the highlights (reference values above 1) and the
rest; how the highlight error falls with τ far beyond level 128; and what a per-material
low-rank linear residual (or a sparse per-value correction) would buy at equal bytes.

One BTF (a dense file, e.g. ``sparsebtf capture copper -o copper40.h5 --size 40 --spp 4``) is
coded at the benchmark's levels (fixed τ per level as ``bench_objective.py``, ε = 0) and at
``--tau-factors`` × level 128's τ (every channel), all from one pass per objective
(:func:`~sparsebtf.codec.encode_levels`). Per objective and τ: linear MSE, the share of the
squared error in values whose reference is above 1 and each part's own MSE, and Table 4's
per-material bytes. "full": every coefficient (the exact projection: orthonormal
dictionaries give the preprocessed point back, so the decode is the preprocessing's round
trip, ``Preprocessor.inverse(forward(reference))``, in float32).

The residual (reference − decoded) of ``--residual-level`` (32) is factorised
(:mod:`sparsebtf.evaluation.residual`, a randomised SVD, conservative: its Ritz values never
exceed the true singular values; ``--exact-spectrum N``: also the exact share from the Gram
matrix's eigenvalues where the smaller side is at most N) in each layout: ``texels``
(H·W × L·V·3), ``directions`` (L·V × H·W·3) and ``channels`` (per channel H·W × L·V, the
total rank shared by singular value, PCA's layout). Per rank r: the share of the residual's
energy removed (ideal), the linear MSE of clamp(decoded + rank-r correction with binary16
factors, 0), the bytes r·(rows + cols)·2 added to the level's, the coder's own MSE at those
total bytes (log-log interpolation over its τ curve; none beyond the largest τ coded) and a
sparse correction's (the largest |residual| values stored exactly at 6 bytes each) at the same
added bytes. ``--pca``: per-material linear PCA (:mod:`sparsebtf.evaluation.baselines`) at the
level's bytes and at each total.

    python benchmarks/bench_glossy_residual.py BTF [--objectives log linear]
        [--levels 16 32 64 128] [--tau-factors 4 16] [--log-offset auto|release|OFFSET]
        [--ranks 1 2 4 8 16] [--layouts texels directions channels] [--pca] [--exact-spectrum N]
        [--seed 0] [--json]
"""

from __future__ import annotations

import argparse
import math
import time
from typing import Any

import numpy as np

from _common import machine, pca_reconstructions, report
from sparsebtf.codec import encode_levels
from sparsebtf.evaluation.benchmark_set import (
    PAPER_TABLE4_RATIOS,
    level_tau,
    paper_level_ratio,
)
from sparsebtf.evaluation.methods.sparse import coded_row
from sparsebtf.evaluation.residual import (
    LAYOUTS,
    channels_correction,
    error_split,
    gram_spectrum,
    low_rank_channels,
    low_rank_curve,
    residual_matrix,
    sparse_values_curve,
    unflatten_residual,
)
from sparsebtf.learning.objective import OBJECTIVES
from sparsebtf.open import open_btf
from sparsebtf.points.preprocessing import Preprocessor
from sparsebtf.runtime.dense import DecodedBTF
from sparsebtf.storage.bundled import load_bundled

LEVELS = (16, 32, 64, 128)
TAU_FACTORS = (4, 16)
RANKS = (1, 2, 4, 8, 16)
SPLIT_KEYS = ("mse", "share_above", "mse_above", "mse_below")


def _split(dec: np.ndarray, ref: np.ndarray) -> dict[str, float]:
    return {k: v for k, v in error_split(dec, ref).items() if k in SPLIT_KEYS}


def at_bytes(curve: list[dict[str, Any]], nbytes: float) -> float | None:
    """The coder's MSE at ``nbytes`` by log-log interpolation over its (bytes, MSE) points;
    None outside them."""
    pts = sorted((r["material_bytes"], r["mse"]) for r in curve if r.get("material_bytes"))
    b = np.log([p[0] for p in pts])
    if not pts or not b[0] <= math.log(nbytes) <= b[-1]:
        return None
    return float(np.exp(np.interp(math.log(nbytes), b, np.log([p[1] for p in pts]))))


def residual_rows(dec: np.ndarray, ref: np.ndarray, level_bytes: int, curve: list[dict[str, Any]],
                  layouts: list[str], ranks: list[int], seed: int,
                  exact_below: int = 0) -> dict[str, Any]:  # fmt: skip
    """The low-rank and sparse corrections of ``ref − dec`` per layout and rank."""
    res = ref - dec
    n = res.size
    out: dict[str, Any] = {}
    for layout in layouts:
        t0 = time.perf_counter()
        if layout == "channels":
            fits, rows = low_rank_channels(res, ranks, oversample=16, power_iters=3, seed=seed)
            m, svals = None, [[float(x) for x in f.s] for f in fits]
        else:
            m = residual_matrix(res, layout)
            fit, rows = low_rank_curve(m, ranks, oversample=16, power_iters=3, seed=seed)
            svals = [float(x) for x in fit.s]
        sparse = sparse_values_curve(res, [r["bytes"] for r in rows])
        for row, sp in zip(rows, sparse, strict=True):
            if layout == "channels":
                corr = channels_correction(fits, tuple(row["ranks"]), res.shape)
            else:
                left, right = fit.factors16(min(row["rank"], len(fit.s)))
                corr = unflatten_residual(left @ right, res.shape, layout)
            fixed = np.maximum(dec + corr, 0)
            total = level_bytes + row["bytes"]
            row.update({
                **{f"corrected_{k}": v for k, v in _split(fixed, ref).items()},
                "mse_unclamped": row.pop("sse_left") / n, "total_bytes": total,
                "coder_mse_at_total": at_bytes(curve, total),
                "sparse_mse": sp["sse_left"] / n, "sparse_values": sp["values"],
            })  # fmt: skip
            del fixed, corr
        if m is not None and exact_below and min(m.shape) <= exact_below:
            ev = gram_spectrum(m)
            for row in rows:
                row["removed_exact"] = float(ev[: row["rank"]].sum() / ev.sum())
        shape = list(m.shape) if m is not None else [3, res.shape[0] * res.shape[1],
                                                     res.shape[2] * res.shape[3]]  # fmt: skip
        out[layout] = {"shape": shape, "ranks": rows, "singular_values": svals,
                       "seconds": time.perf_counter() - t0}  # fmt: skip
        del m
    return out


def pca_rows(btf: Any, ref: np.ndarray, budgets: list[int], seed: int) -> list[dict[str, Any]]:
    """Per-material linear PCA at each byte budget: ranks, bytes, the highlight split."""
    return [{"budget": b, "ranks": ranks, "bytes": n, **_split(rec, ref)}
            for b, ranks, n, rec in pca_reconstructions(btf, budgets, seed)]


def run(spec: str, objectives: list[str], log_offset: str, levels: list[int],
        tau_factors: list[int], ranks: list[int], layouts: list[str], residual_level: int,
        residual_objectives: list[str] | None, pca: bool, seed: int,
        exact_below: int = 0) -> dict[str, Any]:  # fmt: skip
    model = load_bundled()
    btf = open_btf(spec)
    ref = np.asarray(btf.to_array(), dtype=np.float32)
    p = model.patch
    n_pts = (btf.height // p) * (btf.width // p)
    taus = [level_tau(2 * btf.n_values / paper_level_ratio(lv) / n_pts,
                      minimum=tuple(model.tau_train[c] for c in "YUV"))  # type: ignore[arg-type]
            for lv in levels]  # fmt: skip
    atoms = {c: math.prod(int(d.shape[1]) for d in model.dictionaries[c]) for c in "YUV"}
    big = [tuple(min(t * f, atoms[c]) for t, c in zip(taus[-1], "YUV", strict=True))
           for f in tau_factors]  # fmt: skip
    names = [str(lv) for lv in levels] + [f"{levels[-1]}x{f}" for f in tau_factors]
    at = levels.index(residual_level)
    out: dict[str, Any] = {
        "btf": spec, "texels": f"{btf.height}x{btf.width}", "points": n_pts,
        "values_above_1": float((ref > 1).mean()), "max": float(ref.max()),
        "log_offset": log_offset, "taus": dict(zip(names, taus + big, strict=True)),
        "residual_level": residual_level, "objectives": {},
    }  # fmt: skip
    for obj in objectives:
        t0 = time.perf_counter()
        coded = encode_levels(btf, model, taus + big, eps=0.0, log_offset=log_offset,
                              progress=False, objective=obj, allow_below_training=True)
        secs = time.perf_counter() - t0
        curve, dec_at = [], None
        for name, c in zip(names, coded, strict=True):
            dec = np.asarray(DecodedBTF(c).to_array(), dtype=np.float32)
            curve.append({"tau": name, "taus": list(c.resolve_tau(None)),
                          "material_bytes": coded_row(c, model)["material_bytes"],
                          **_split(dec, ref)})  # fmt: skip
            if name == str(residual_level):
                dec_at = dec
            del dec
        pre = Preprocessor(coded[0].stats)
        full = np.asarray(pre.inverse(pre.forward(ref, dtype=np.float32)), dtype=np.float32)
        curve.append({"tau": "full", "taus": [atoms[c] for c in "YUV"], "material_bytes": None,
                      **_split(full, ref)})  # fmt: skip
        del full
        entry: dict[str, Any] = {"curve": curve, "encode_seconds": secs,
                                 "log_offset_value": float(coded[0].stats.log_offset)}
        if residual_objectives is None or obj in residual_objectives:
            assert dec_at is not None
            entry["residual"] = residual_rows(dec_at, ref, curve[at]["material_bytes"],
                                              curve[:-1], layouts, ranks, seed,
                                              exact_below)  # fmt: skip
        out["objectives"][obj] = entry
        del dec_at, coded
    if pca:
        first = out["objectives"][objectives[0]]
        budgets = [first["curve"][at]["material_bytes"]]
        for res in first.get("residual", {}).values():
            budgets += [r["total_bytes"] for r in res["ranks"]]
        out["pca"] = pca_rows(btf, ref, sorted(set(budgets)), seed)
    return out


def _rows(data: dict[str, Any]) -> list[tuple[str, str]]:
    rows: list[tuple[str, str]] = [
        ("material", f"{data['btf']} ({data['texels']}, {data['points']} points): "
                     f"{data['values_above_1']:.2%} of the values above 1, max "
                     f"{data['max']:.1f}; log offset {data['log_offset']}"),
        ("tau", ", ".join(f"{k}: {'/'.join(map(str, v))}" for k, v in data["taus"].items())),
    ]  # fmt: skip
    for obj, e in data["objectives"].items():
        rows.append((obj, f"log offset {e['log_offset_value']:.3g}; encode "
                          f"{e['encode_seconds']:.0f} s"))
        for r in e["curve"]:
            b = f"{r['material_bytes']:,d} B" if r["material_bytes"] else "-"
            rows.append((f"  {r['tau']}", f"{b}: linear MSE {r['mse']:.4g}, {r['share_above']:.1%}"
                         f" of it above 1 (MSE there {r['mse_above']:.4g}, below "
                         f"{r['mse_below']:.4g})"))  # fmt: skip
        for layout, res in e.get("residual", {}).items():
            rows.append((f"  residual {data['residual_level']}, {layout}",
                         "x".join(map(str, res["shape"])) + f" ({res['seconds']:.0f} s)"))
            for r in res["ranks"]:
                cm = r["coder_mse_at_total"]
                split = f" ({'/'.join(map(str, r['ranks']))})" if "ranks" in r else ""
                rows.append((f"    rank {r['rank']}{split}", (
                    f"+{r['bytes']:,d} B (total {r['total_bytes']:,d}): removes "
                    f"{r['removed_ideal']:.1%} of the residual energy"
                    + (f" (exact {r['removed_exact']:.1%})" if "removed_exact" in r else "")
                    + "; MSE "
                    f"{r['corrected_mse']:.4g} ({r['corrected_share_above']:.1%} above 1); "
                    f"coder at the same bytes {'-' if cm is None else f'{cm:.4g}'}; sparse "
                    f"values ({r['sparse_values']:,d}) {r['sparse_mse']:.4g}")))
    for r in data.get("pca", []):
        rows.append((f"PCA {r['budget']:,d} B", f"ranks {r['ranks']} ({r['bytes']:,d} B): MSE "
                     f"{r['mse']:.4g}, {r['share_above']:.1%} above 1"))
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("btf")
    ap.add_argument("--objectives", nargs="+", choices=OBJECTIVES, default=["log", "linear"])
    ap.add_argument("--levels", nargs="+", type=int, default=list(LEVELS),
                    choices=sorted(PAPER_TABLE4_RATIOS))
    ap.add_argument("--tau-factors", nargs="*", type=int, default=list(TAU_FACTORS),
                    help="also code at these multiples of the last level's tau")
    ap.add_argument("--log-offset", default="auto")
    ap.add_argument("--ranks", nargs="+", type=int, default=list(RANKS))
    ap.add_argument("--layouts", nargs="+", choices=LAYOUTS, default=["texels", "directions"])
    ap.add_argument("--residual-level", type=int, default=32)
    ap.add_argument("--residual-objectives", nargs="*", choices=OBJECTIVES,
                    help="objectives whose residual is factorised (default: all)")
    ap.add_argument("--pca", action="store_true", help="linear PCA at the same bytes")
    ap.add_argument("--exact-spectrum", type=int, default=0, metavar="N",
                    help="also the exact energy removed (Gram eigenvalues) in layouts whose "
                         "smaller side is at most N")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--json", action="store_true")
    a = ap.parse_args()
    if a.residual_level not in a.levels:
        ap.error(f"--residual-level {a.residual_level} is not among --levels")
    data = run(a.btf, a.objectives, a.log_offset, a.levels, a.tau_factors, a.ranks, a.layouts,
               a.residual_level, a.residual_objectives, a.pca, a.seed, a.exact_spectrum)
    data["machine"] = machine()
    report(_rows(data), data, a.json)


if __name__ == "__main__":
    main()

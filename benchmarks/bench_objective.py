"""Coding objectives (issue 32): the error of each storage level under ``--objective``
log / linear / display, on the bundled ``release`` model (K = 8, 10×10×151×151 points).

One BTF (a dense file, e.g. ``sparsebtf capture copper -o copper.h5 --size 40 --spp 1``, or a
``synth:`` spec) is coded at the benchmark's levels 16/32/64/128 (fixed τ per level from the
per-material ratio of the paper's SparseBTF(L), chroma at least τ_l; ε = 0) under each
objective, all levels from one pass (:func:`~sparsebtf.codec.encode_levels`). Per objective
and level: the MSE of linear RGB, of the display mapping (1.3·I^(1/1.8), clipped at 1) and of
ln(RGB + 1e-5) over every value, and the per-material bytes (Table 4); per objective the data
points whose linear MSE rose from one level to the next, and the encode time per point (wall
clock, so on a loaded machine only their ratio means much).

``--lod``: level 32 decoded at the runtime's level-of-detail fractions 0.1, 0.3, 0.5 and 1 of
τ (every channel, as :mod:`sparsebtf.runtime.lod` truncates), the linear MSE at each and the
points whose linear MSE rose from one fraction to the next.

``--pca``: per-material linear PCA (:mod:`sparsebtf.evaluation.baselines`, ranks shared by
singular value) at the bytes of the log objective's SparseBTF(32) and at twice them (the
paper's Table 5 test), beside each objective's level-32 linear MSE.

``--render DIR``: each objective's level-32 code rendered with the dense Mitsuba plugin beside
the dense reference, same scene, spp and seed (:func:`~sparsebtf.evaluation.renders.
render_methods`): image MSE (linear, display-mapped) and mean HDR-ꟻLIP per objective, the
strip in ``DIR/figure8.png``.

    python benchmarks/bench_objective.py BTF [--objectives log linear display]
        [--levels 16 32 64 128] [--log-offset auto|release|OFFSET] [--lod] [--pca]
        [--render DIR --spp 16 --image-size 128] [--json]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path
from typing import Any

import numpy as np

from _common import machine, pca_reconstructions, report
from sparsebtf.codec import encode_levels
from sparsebtf.display import tone_map
from sparsebtf.evaluation.benchmark_set import (
    PAPER_TABLE4_RATIOS,
    level_tau,
    paper_level_ratio,
)
from sparsebtf.learning.objective import OBJECTIVES
from sparsebtf.open import open_btf
from sparsebtf.runtime import coded_btf_view
from sparsebtf.runtime.dense import DecodedBTF
from sparsebtf.storage.bundled import load_bundled

LEVELS = (16, 32, 64, 128)
#: the level-of-detail fractions of τ ``--lod`` decodes at (the runtime's LATER_FRACTION,
#: SAMPLED_FRACTION, MIN_FRACTION and the full τ)
LOD_FRACTIONS = (0.1, 0.3, 0.5, 1.0)


def _point_mse(dec: np.ndarray, ref: np.ndarray, p: int) -> np.ndarray:
    """(P,) linear-RGB MSE of each p×p data point."""
    h, w = ref.shape[0] // p, ref.shape[1] // p
    return ((dec - ref) ** 2).reshape(h, p, w, p, -1).mean(axis=(1, 3, 4)).ravel()


def lod_curve(coded: Any, ref: np.ndarray, p: int) -> dict[str, Any]:
    """Linear MSE of ``coded`` at the level-of-detail fractions :data:`LOD_FRACTIONS` of its
    τ (every channel), and the points whose MSE rose from one fraction to the next."""
    from sparsebtf.runtime import RuntimeBTF
    from sparsebtf.runtime.lod import lod_tau

    taus = coded.resolve_tau(None)
    mses, per = [], []
    for f in LOD_FRACTIONS:
        t = lod_tau(taus, np.array([f]))[0]
        rt = RuntimeBTF(coded, tau=tuple(int(np.floor(x)) for x in t))
        dec = DecodedBTF(rt.coded).to_array().astype(np.float64)
        mses.append(float(((dec - ref) ** 2).mean()))
        per.append(_point_mse(dec, ref, p))
    pp = np.array(per)
    return {"fractions": list(LOD_FRACTIONS), "mse_linear": mses,
            "points_worse": [int((pp[i + 1] > pp[i]).sum()) for i in range(len(pp) - 1)]}


def pca_at(btf: Any, ref: np.ndarray, material_bytes: int) -> dict[str, Any]:
    """Per-material linear PCA at ``material_bytes`` and twice them: ranks, bytes, MSE."""
    found = pca_reconstructions(btf, [material_bytes, 2 * material_bytes], seed=0)
    return {f"{factor}x": {"ranks": ranks, "bytes": n,
                           "mse_linear": float(((rec.astype(np.float64) - ref) ** 2).mean())}
            for factor, (_, ranks, n, rec) in zip((1, 2), found, strict=True)}


def run(spec: str, objectives: list[str], log_offset: str, levels: list[int],
        lod: bool = False, pca: bool = False, render: str | None = None, spp: int = 16,
        image_size: int = 128) -> dict[str, Any]:  # fmt: skip
    from sparsebtf.evaluation.methods.sparse import coded_row

    model = load_bundled()
    btf = open_btf(spec)
    ref = btf.to_array().astype(np.float64)
    p = model.patch
    n_pts = (btf.height // p) * (btf.width // p)
    taus = [level_tau(2 * btf.n_values / paper_level_ratio(lv) / n_pts,
                      minimum=tuple(model.tau_train[c] for c in "YUV"))  # type: ignore[arg-type]
            for lv in levels]  # fmt: skip
    at32 = levels.index(32) if 32 in levels else len(levels) // 2
    out: dict[str, Any] = {
        "btf": spec, "texels": f"{btf.height}x{btf.width}", "points": n_pts,
        "zeros": float((ref == 0).mean()), "above_1": float((ref > 1).mean()),
        "max": float(ref.max()), "log_offset": log_offset, "taus": taus, "objectives": {},
    }  # fmt: skip
    ref_disp, ref_log = tone_map(ref), np.log(ref + 1e-5)
    views: dict[str, Any] = {}
    for obj in objectives:
        t0 = time.perf_counter()
        coded = encode_levels(btf, model, taus, eps=0.0, log_offset=log_offset,
                              progress=False, objective=obj, allow_below_training=True)
        secs = time.perf_counter() - t0
        rows, per_point = [], []
        for lv, c in zip(levels, coded, strict=True):
            dec = DecodedBTF(c).to_array().astype(np.float64)
            err = (dec - ref) ** 2
            per_point.append(_point_mse(dec, ref, p))
            rows.append({
                "level": lv, "mse_linear": float(err.mean()),
                "mse_display": float(((tone_map(dec) - ref_disp) ** 2).mean()),
                "mse_log": float(((np.log(np.maximum(dec, 0) + 1e-5) - ref_log) ** 2).mean()),
                "material_bytes": coded_row(c, model)["material_bytes"],
            })  # fmt: skip
        pp = np.array(per_point)
        out["objectives"][obj] = {
            "levels": rows, "seconds": secs, "seconds_per_point": secs / n_pts,
            "points_worse": [int((pp[i + 1] > pp[i]).sum()) for i in range(len(levels) - 1)],
        }  # fmt: skip
        if lod:
            out["objectives"][obj]["lod"] = lod_curve(coded[at32], ref, p)
        views[obj] = coded_btf_view(coded[at32])
    first = out["objectives"][objectives[0]]["levels"][at32]
    if pca:
        out["pca"] = {"level": levels[at32], "sparsebtf_bytes": first["material_bytes"],
                      **pca_at(btf, ref, first["material_bytes"])}  # fmt: skip
    if render:
        from sparsebtf.evaluation.renders import render_methods

        res = render_methods(btf, {f"{o} ({levels[at32]})": v for o, v in views.items()},
                             Path(render), spp=spp, image_size=image_size, seed=0,
                             progress=False)  # fmt: skip
        out["render"] = {"spp": spp, "image_size": image_size, "level": levels[at32],
                         "figure": str(Path(render) / "figure8.png"),
                         "methods": {k: {m: v[m] for m in ("image_mse", "image_mse_display",
                                                         "flip")}
                                     for k, v in res.items()}}  # fmt: skip
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("btf")
    ap.add_argument("--objectives", nargs="+", choices=OBJECTIVES, default=list(OBJECTIVES))
    ap.add_argument("--levels", nargs="+", type=int, default=list(LEVELS),
                    choices=sorted(PAPER_TABLE4_RATIOS))
    ap.add_argument("--log-offset", default="auto")
    ap.add_argument("--lod", action="store_true", help="level 32 at the LOD fractions")
    ap.add_argument("--pca", action="store_true", help="linear PCA at 1x and 2x the bytes")
    ap.add_argument("--render", metavar="DIR", help="render level 32 per objective into DIR")
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--image-size", type=int, default=128)
    ap.add_argument("--json", action="store_true")
    a = ap.parse_args()
    data = run(a.btf, a.objectives, a.log_offset, a.levels, a.lod, a.pca, a.render, a.spp,
               a.image_size)
    data["machine"] = machine()
    rows: list[tuple[str, str]] = [
        ("material", f"{data['btf']} ({data['texels']}, {data['points']} points): "
                     f"{data['zeros']:.1%} zeros, {data['above_1']:.1%} above 1, "
                     f"max {data['max']:.1f}; log offset {data['log_offset']}"),
    ]  # fmt: skip
    lvs = "/".join(str(x["level"]) for x in next(iter(data["objectives"].values()))["levels"])
    for obj, r in data["objectives"].items():
        lin = ", ".join(f"{x['mse_linear']:.4g}" for x in r["levels"])
        disp = ", ".join(f"{x['mse_display']:.4g}" for x in r["levels"])
        log = ", ".join(f"{x['mse_log']:.4g}" for x in r["levels"])
        nbytes = ", ".join(f"{x['material_bytes']:,d}" for x in r["levels"])
        rows.append((obj, f"linear MSE at {lvs}: {lin}; display {disp}; log {log}; bytes "
                          f"{nbytes}; points worse than the level below {r['points_worse']}; "
                          f"{r['seconds_per_point']:.2f} s/point"))  # fmt: skip
        if "lod" in r:
            lod = r["lod"]
            rows.append((f"{obj}, LOD", "linear MSE at fractions "
                         f"{'/'.join(map(str, lod['fractions']))} of tau: "
                         + ", ".join(f"{x:.4g}" for x in lod["mse_linear"])
                         + f"; points worse than the fraction below {lod['points_worse']}"))
    if "pca" in data:
        q = data["pca"]
        rows.append(("linear PCA", f"at SparseBTF({q['level']})'s {q['sparsebtf_bytes']:,d} B: "
                     f"MSE {q['1x']['mse_linear']:.4g} (ranks {q['1x']['ranks']}, "
                     f"{q['1x']['bytes']:,d} B); at 2x: {q['2x']['mse_linear']:.4g} (ranks "
                     f"{q['2x']['ranks']}, {q['2x']['bytes']:,d} B)"))  # fmt: skip
    if "render" in data:
        g = data["render"]
        for k, v in g["methods"].items():
            rows.append((f"render {k}", f"{g['spp']} spp, {g['image_size']}^2: image MSE "
                         f"{v['image_mse']:.4g}, display {v['image_mse_display']:.4g}, "
                         f"HDR-FLIP {v['flip']:.4f}"))
        rows.append(("render strip", g["figure"]))
    report(rows, data, a.json)


if __name__ == "__main__":
    main()

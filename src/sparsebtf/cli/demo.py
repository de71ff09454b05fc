"""``sparsebtf demo``: the whole pipeline on synthetic materials at UBO2014 directions.

1. synthesise training materials and unseen test materials (cached on disk);
2. train a model (three ensembles, Y/U/V) once;
3. encode each test material at several sparsity levels τ (one projection pass per material);
4. code the same materials with the bundled ``release`` model (the authors' ensembles, trained
   on 18 measured UBO2014 materials) at the release's τ, beside the trained model's rows;
5. print a table (model, τ, bytes, ratios, MSE, PSNR, SSIM) and write ``results.json``; write
   reference / reconstruction / false-colour error PNGs and a quality–storage plot.
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..learning.codes import RELEASE_TAU, RELEASE_TAU_TRAIN
from ._args import check_output_dir, integer

__all__ = ["DemoConfig", "register", "run_demo"]


@dataclass(frozen=True)
class DemoConfig:
    """Sizes of the demo run (the defaults finish in a few minutes on 2 cores)."""

    train_materials: tuple[tuple[str, int], ...] = (
        ("carpet", 1),
        ("fabric", 1),
        ("leather", 1),
        ("stone", 1),
        ("wood", 1),
    )
    test_materials: tuple[tuple[str, int], ...] = (("felt", 7), ("wallpaper", 7))
    train_size: int = 40
    test_size: int = 60
    directions: str = "ubo2014"
    n_dictionaries: int = 4
    tau_train: tuple[int, int, int] = RELEASE_TAU_TRAIN
    sample: float = 0.5
    iters: int = 3
    taus: tuple[tuple[int, int, int], ...] = (
        (256, 32, 32),
        (512, 48, 48),
        (885, 64, 64),
        (1770, 128, 128),
    )
    ssim_images: int = 16
    #: τ at which the bundled model codes the test materials (the release's).
    bundled_tau: tuple[int, int, int] = RELEASE_TAU

    @classmethod
    def quick(cls) -> DemoConfig:
        return cls(
            train_materials=(("carpet", 1), ("stone", 1), ("wood", 1)),
            test_materials=(("felt", 7),),
            train_size=20,
            test_size=30,
            n_dictionaries=3,
            iters=2,
            taus=((256, 32, 32), (885, 64, 64)),
            ssim_images=8,
        )


def _pairs(btf: Any) -> list[tuple[int, int]]:
    """The paper's figure configurations, snapped to the nearest sampled directions."""

    def d(theta: float, phi: float) -> np.ndarray:
        t, p = np.radians(theta), np.radians(phi)
        return np.array([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)])

    wanted = [
        ((23.5, 270.0), (11.0, 15.0)),  # Figures 4 and 6
        ((45.0, 0.0), (60.0, 15.0)),  # Figure 5 (view elevation 30°)
        ((60.0, 90.0), (30.0, 195.0)),
    ]  # a grazing light, the other side
    out = []
    for (lt, lp), (vt, vp) in wanted:
        li = int(btf.lights.nearest(d(lt, lp))[0][0])
        vi = int(btf.views.nearest(d(vt, vp))[0][0])
        out.append((li, vi))
    return out


def run_demo(
    out: Path,
    quick: bool = False,
    seed: int = 0,
    as_json: bool = False,
    config: DemoConfig | None = None,
) -> dict[str, Any]:
    """Run the demo into folder ``out``; returns (and writes) the results object."""
    # The whole pipeline, imported here so that ``sparsebtf --help`` stays fast.
    from ..codec import encode_levels, train
    from ..data.synth import cached
    from ..figures import comparison_grid, quality_plot
    from ..metrics import compare
    from ..runtime import coded_btf_view
    from ..storage import save_coded, save_model, storage_report

    cfg = config or (DemoConfig.quick() if quick else DemoConfig())
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    print(
        f"[1/5] synthesising {len(cfg.train_materials)} training and "
        f"{len(cfg.test_materials)} test materials ({cfg.directions} directions)"
    )
    train_btfs = [
        cached(m, cfg.train_size, cfg.directions, s + seed, progress=None)
        for m, s in cfg.train_materials
    ]
    test_btfs = [
        cached(m, cfg.test_size, cfg.directions, s + seed, progress=None)
        for m, s in cfg.test_materials
    ]
    print(
        f"[2/5] training K={cfg.n_dictionaries} dictionaries per channel, "
        f"tau_train={cfg.tau_train}, {cfg.iters} iterations"
    )
    model = train(
        train_btfs,
        n_dictionaries=cfg.n_dictionaries,
        tau_train=cfg.tau_train,
        sample=cfg.sample,
        max_iter=cfg.iters,
        seed=seed,
    )
    del train_btfs  # their files (and chunk caches) close: memory for the next steps
    save_model(model, out / "model.h5")
    for ch, t in model.training.items():
        print(
            f"      {ch}: objective {t['objective'][0]:.4f} -> {t['objective'][-1]:.4f} "
            f"(mean squared error per value, standardised), points per dictionary "
            f"{'/'.join(map(str, t['membership_counts']))}"
        )
    print(f"[3/5] encoding unseen materials at tau = {', '.join(map(str, cfg.taus))}")
    rows: list[dict[str, Any]] = []

    def row(btf: Any, coded: Any, path: Path, label: str, which: str) -> Any:
        save_coded(coded, path)
        view = coded_btf_view(coded)
        m = compare(btf, view, stats=coded.stats, ssim_images=cfg.ssim_images)
        rep = storage_report(coded, coded.model, path)
        keys = ("nnz", "bytes_coefficients", "bytes_dictionaries", "bytes_total", "bytes_raw",
                "compression_ratio", "compression_ratio_table4_material",
                "compression_ratio_per_material", "bytes_stored", "file_bytes")
        rows.append({
            "material": btf.name, "model": which, "tau": label,
            **{k: m[k] for k in ("mse_rgb", "psnr_rgb", "ssim", "mse_log", "mse_std")},
            **{k: rep[k] for k in keys},
            "ratio_coefficients_only": rep["bytes_raw"] / rep["bytes_coefficients"],
        })  # fmt: skip
        return view

    for btf in test_btfs:
        levels = encode_levels(btf, model, list(cfg.taus))
        recs = {}
        for taus, coded in zip(cfg.taus, levels, strict=True):
            label = "/".join(map(str, taus))
            path = out / f"{btf.name}_tau{taus[0]}.h5"
            recs[f"tau {label}"] = row(btf, coded, path, label, "trained")
        grid = comparison_grid(
            btf,
            {k: recs[k] for k in list(recs)[:: max(1, len(recs) // 2)]},
            _pairs(btf),
            out / f"{btf.name}_comparison.png",
        )
        print(f"      wrote {grid}")
    bundled = _bundled_rows(cfg, test_btfs, out, row)
    plot = quality_plot([r for r in rows if r["model"] == "trained"],
                        out / "quality_vs_storage.png", x="bytes_coefficients")  # fmt: skip
    print(
        "[5/5] results. MSE on linear RGB, PSNR = 10·log10(1/MSE) (peak 1). 'coef bytes' as "
        "the paper's Table 4; 'file bytes' what the coded file stores (codes, statistics, "
        "directions, header); 'ratio' = raw fp16 bytes / file bytes; 'T4 ratio' = raw / the "
        "Table 4 codes; 'T4+dict' also counts the model's dictionaries, which every material "
        "coded on it shares"
    )
    header = (
        f"{'material':<24} {'model':<8} {'tau (Y/U/V)':<14} {'coef bytes':>11} "
        f"{'file bytes':>11} {'ratio':>8} {'T4 ratio':>9} {'T4+dict':>8} {'MSE':>10} "
        f"{'PSNR dB':>8} {'SSIM':>6}"
    )
    print(header)
    print("-" * len(header))
    for r in sorted(rows, key=lambda r: r["material"]):
        print(
            f"{r['material']:<24} {r['model']:<8} {r['tau']:<14} {r['bytes_coefficients']:>11,d} "
            f"{r['bytes_stored']:>11,d} {r['compression_ratio_per_material']:>8.1f} "
            f"{r['compression_ratio_table4_material']:>9.1f} {r['compression_ratio']:>8.1f} "
            f"{r['mse_rgb']:>10.3e} {r['psnr_rgb']:>8.2f} {r['ssim']:>6.3f}"
        )
    if bundled:
        print(f"      ({bundled})")
    result = {
        "config": {k: getattr(cfg, k) for k in cfg.__dataclass_fields__},
        "model_hash": model.content_hash,
        "training": model.training,
        "rows": rows,
        "seconds": time.perf_counter() - t0,
    }
    (out / "results.json").write_text(json.dumps(result, indent=2, default=str))
    print(f"wrote {plot}, {out / 'results.json'} ({result['seconds']:.0f} s)")
    if as_json:
        print(json.dumps(result, indent=2, default=str))
    return result


def _bundled_rows(cfg: DemoConfig, test_btfs: list[Any], out: Path, row: Any) -> str:
    """Step 4: the test materials coded with the bundled ``release`` model, as more rows.

    Returns a note for the table (what the bundled rows are, or why there are none)."""
    from ..codec import encode
    from ..storage.bundled import DEFAULT_MODEL, bundled_models, load_bundled

    if DEFAULT_MODEL not in bundled_models():
        print("[4/5] skipped: no bundled model in this installation")
        return ""
    release = load_bundled(DEFAULT_MODEL)
    fits = [b for b in test_btfs if b.lights.equals(release.lights)
            and b.views.equals(release.views) and b.height % release.patch == 0
            and b.width % release.patch == 0]  # fmt: skip
    if not fits:
        print(f"[4/5] skipped: the bundled model covers {release.lights.name} directions and "
              f"{release.patch}x{release.patch} patches, these test materials do not fit")
        return ""
    label = "/".join(map(str, cfg.bundled_tau))
    print(f"[4/5] coding them with the bundled '{DEFAULT_MODEL}' model (the authors' ensembles, "
          f"trained on 18 measured UBO2014 materials) at tau = {label}")
    for btf in fits:
        coded = encode(btf, release, tau=cfg.bundled_tau)
        row(btf, coded, out / f"{btf.name}_release_tau{cfg.bundled_tau[0]}.h5", label, "release")
    return (f"'release' rows: the bundled model, K = {release.n_dictionaries('Y')} per channel; "
            f"ratio+dict counts its {release.dictionary_entries('Y') * 6 / 2**20:.1f} MiB of "
            "dictionaries")


def run(args: argparse.Namespace) -> int:
    check_output_dir(args.out, "--out")
    run_demo(Path(args.out), quick=args.quick, seed=args.seed, as_json=args.json)
    return 0


def register(sub: Any) -> None:
    s = sub.add_parser("demo", help="synthesise, train, encode at several tau, report and plot")
    s.add_argument("--out", default="sparsebtf-demo", help="output folder (default sparsebtf-demo)")
    s.add_argument("--quick", action="store_true", help="smaller sizes (about a minute)")
    s.add_argument("--seed", type=int, default=0,
                   help="shifts every material's seed and the training seed (default 0)")
    s.add_argument("--json", action="store_true", help="also print the results as JSON")
    s.set_defaults(func=run, checks={"seed": integer(0, 2**32 - 1)})

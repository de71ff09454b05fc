"""Stored bytes of coded files (schema 3) against the paper's Table 4 and schema 2.

The benchmark's unseen materials (``sparsebtf.evaluation.benchmark_set``: seven synthetic
classes, seeds 12 and 13, 30×30 texels, UBO2014 directions) and one 100×100 material (the
Table 5 carpet), coded on the bundled ``release`` model at the storage levels 16/32/64/128
with the benchmark's fixed τ per level (eps = 0: every point keeps exactly τ coefficients).
For every material and level:

* Table 4's per-material bytes (5 B per coefficient, 2 B per point and channel) and the
  schema-3 file's stored codes, statistics, directions and header (they add up to its size);
* the per-material ratio raw / file bytes, and at 400×400 extrapolated (the codes' stored
  bytes per data point × 1600 plus this file's statistics, directions and header);
* on the 100×100 material, the time to read the file (schema 2 vs 3, best of 5) and to read
  it and decode every data point (Eq. 4, all channels, best of 3), the schemas interleaved;
* at level 128 (on the seed-12 materials), what binary16 statistics cost: the encoder rounds
  μ and σ to binary16 before coding (schema 3 stores them in 2 bytes); the linear-RGB MSE of
  that encoding against the same encoding with float32 statistics, and of rounding float32
  statistics after coding, as shares of the codes' own MSE, and the stored bytes of both.

    python benchmarks/bench_storage.py [--quick] [--json]
    python benchmarks/bench_storage.py --timing --repeat 9     # the timing alone, idle machine

``--quick``: the seven seed-12 materials at 20×20 and a 40×40 one (about a minute).
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import replace
from pathlib import Path
from tempfile import TemporaryDirectory
from typing import Any
from unittest import mock

import numpy as np

from _common import machine
from sparsebtf.codec import encode_levels
from sparsebtf.data.synth import cached
from sparsebtf.evaluation.benchmark_set import BenchConfig, level_tau
from sparsebtf.evaluation.report import table_stored
from sparsebtf.learning.coding import reconstruct_points
from sparsebtf.metrics import compare
from sparsebtf.runtime import coded_btf_view
from sparsebtf.storage import load_coded, save_coded, storage_report
from sparsebtf.storage.accounting import stored_bytes
from sparsebtf.storage.bundled import load_bundled

LEVELS = (16, 32, 64, 128)
UBO_POINTS = 1600  # 400×400 texels in 10×10 patches


def materials(quick: bool) -> tuple[list[tuple[str, int, int]], tuple[str, int, int]]:
    """(class, seed, size) of the unseen materials and of the large one."""
    cfg = BenchConfig()
    if quick:
        return [(c, 12, 20) for c in cfg.classes], ("carpet", 12, 40)
    large = (*cfg.table5_materials[0], cfg.table5_size)
    return [(c, s, cfg.test_size) for c, s in cfg.test_set()], large  # type: ignore[return-value]


def level_taus(levels: tuple[int, ...], tau_l: tuple[int, ...]) -> dict[int, tuple[int, int, int]]:
    """τ of each level as the benchmark codes it: the per-material ratio of SparseBTF(L),
    chroma at least the model's τ_l."""
    ratios = BenchConfig(levels=levels).ratios()
    point_raw = 10 * 10 * 151 * 151 * 3 * 2
    return {lv: level_tau(point_raw / ratios[lv], minimum=tau_l) for lv in levels}


def _row(name: str, lv: int, tau: tuple, coded: Any, model: Any, path: Path) -> dict[str, Any]:
    rep = storage_report(coded, model, path)
    p = coded.n_points
    fixed = rep["bytes_stored_stats"] + rep["bytes_stored_directions"] + rep["bytes_stored_header"]
    raw400 = 400 * 400 * 151 * 151 * 3 * 2
    codes400 = rep["bytes_stored_codes"] / p * UBO_POINTS
    t4_400 = rep["bytes_table4_material"] / p * UBO_POINTS
    return {
        "material": name, "level": lv, "tau": list(tau), "n_points": p,
        "table4_material_bytes": rep["bytes_table4_material"],
        "stored_codes_bytes": rep["bytes_stored_codes"],
        "stored_codes_vs_table4": rep["stored_codes_vs_table4"],
        "stored_stats_bytes": rep["bytes_stored_stats"],
        "stored_directions_bytes": rep["bytes_stored_directions"],
        "stored_header_bytes": rep["bytes_stored_header"],
        "stored_bytes": rep["bytes_stored"],
        "ratio_stored": rep["compression_ratio_per_material"],
        "ratio_table4": rep["compression_ratio_table4_material"],
        "ratio_stored_400": raw400 / (codes400 + fixed),
        "ratio_table4_400": raw400 / t4_400,
    }  # fmt: skip


def _read_decode(p2: Path, p3: Path, model: Any, points: np.ndarray,
                 repeat: int = 3) -> dict[str, float]:  # fmt: skip
    """Read time of each schema and read + decode of ``points`` (Eq. 4, every channel): the
    schemas' runs interleaved, best of ``repeat`` (best of 5 for the reads alone)."""

    def read(path: Path) -> Any:
        return load_coded(path, model)

    def decode(coded: Any) -> None:
        for ch in coded.channels:
            reconstruct_points(coded.codes[ch], model.dictionaries[ch], points, np.float32)

    def timed(fn: Any) -> float:
        t = time.perf_counter()
        fn()
        return time.perf_counter() - t

    read(p2), read(p3)  # the watchdog walks each file once
    reads = {p2: [], p3: []}
    both = {p2: [], p3: []}
    for i in range(max(5, repeat)):
        for path in (p2, p3) if i % 2 == 0 else (p3, p2):
            reads[path].append(timed(lambda path=path: read(path)))
            if i < repeat:
                both[path].append(timed(lambda path=path: decode(read(path))))
    r2, r3 = min(reads[p2]), min(reads[p3])
    b2, b3 = min(both[p2]), min(both[p3])
    return {"read_v2_s": r2, "read_v3_s": r3, "read_decode_v2_s": b2, "read_decode_v3_s": b3,
            "read_ratio": r3 / r2, "read_decode_ratio": b3 / b2}  # fmt: skip


def _fp16_stats(btf: Any, model: Any, tau: tuple, coded16: Any, tmp: Path) -> dict[str, float]:
    """What binary16 statistics cost in linear-RGB MSE: the encoder's rounding of μ, σ before
    coding (``coded16``, as sparsebtf encodes) against the same encoding with float32
    statistics, and rounding float32 statistics after coding, against the codes' own error."""
    from sparsebtf.codec import jobs

    with mock.patch.object(jobs, "binary16_statistics", lambda s: s):
        (raw,) = encode_levels(btf, model, [tau], eps=0.0, progress=False)
    coded32 = load_coded(save_coded(raw, tmp / "f32.h5"), model)
    after = replace(coded32, stats=replace(
        coded32.stats, mean=coded32.stats.mean.astype(np.float16).astype(np.float64),
        std=coded32.stats.std.astype(np.float16).astype(np.float64),
    )).attach(model)  # fmt: skip
    v32 = coded_btf_view(coded32)
    codes = compare(btf, v32, ssim_images=0, progress=False)["mse_rgb"]
    rounded = compare(btf, coded_btf_view(coded16), ssim_images=0, progress=False)["mse_rgb"]
    moved = compare(v32, coded_btf_view(after), ssim_images=0, progress=False)["mse_rgb"]
    return {"mse_codes_fp32_stats": codes, "mse_codes_fp16_stats": rounded,
            "mse_increase": rounded - codes, "mse_rounding_after_coding": moved,
            "stats_bytes_fp32": stored_bytes(tmp / "f32.h5")["bytes_stored_stats"]}  # fmt: skip


def run(quick: bool, levels: tuple[int, ...] = LEVELS, timing_only: bool = False,
        repeat: int = 3) -> dict[str, Any]:  # fmt: skip
    model = load_bundled()
    taus = level_taus(levels, tuple(model.params["tau_train"][ch] for ch in model.channels))
    unseen, large = materials(quick)
    if timing_only:  # the read / decode timing alone, on the large material
        unseen = []
    rows, timing, fp16 = [], [], []
    t0 = time.perf_counter()
    with TemporaryDirectory() as tmp:
        d = Path(tmp)
        for cls, seed, size in [*unseen, large]:
            btf = cached(cls, size=size, seed=seed)
            coded_levels = encode_levels(btf, model, [taus[lv] for lv in levels], eps=0.0,
                                         progress=False)  # fmt: skip
            for lv, coded in zip(levels, coded_levels, strict=True):
                p3 = save_coded(coded, d / f"{btf.name}_{lv}.h5")
                rows.append(_row(btf.name, lv, taus[lv], coded, model, p3))
                if (cls, seed, size) == large:
                    p2 = save_coded(coded, d / f"{btf.name}_{lv}_v2.h5", schema=2)
                    pts = np.arange(coded.n_points)
                    timing.append({"material": btf.name, "level": lv,
                                   **_read_decode(p2, p3, model, pts, repeat)})  # fmt: skip
                elif lv == max(levels) and seed == unseen[0][1]:
                    fp16.append({"material": btf.name, "level": lv, **_fp16_stats(
                        btf, model, taus[lv], load_coded(p3, model), d)})  # fmt: skip
    stats_f16 = float(np.mean([r["stored_stats_bytes"] for r in rows]))
    return {
        "benchmark": "bench_storage", "quick": quick, "machine": machine(),
        "model": "release (bundled)", "levels": list(levels),
        "taus": {str(k): list(v) for k, v in taus.items()},
        "rows": rows, "timing": timing, "fp16_stats": fp16,
        "fp16_stats_summary": _fp16_summary(fp16, stats_f16) if fp16 else None,
        "seconds": time.perf_counter() - t0,
    }  # fmt: skip


def _fp16_summary(fp16: list[dict[str, float]], stats_bytes: float) -> dict[str, float]:
    """Means over the materials; shares of the codes' own error (float32 statistics)."""
    if not fp16:
        return {}

    def mean(key: str) -> float:
        return float(np.mean([r[key] for r in fp16]))

    codes = mean("mse_codes_fp32_stats")
    return {"mse_codes_fp32_stats": codes, "mse_increase": mean("mse_increase"),
            "share_increase": mean("mse_increase") / codes,
            "mse_rounding_after_coding": mean("mse_rounding_after_coding"),
            "share_rounding_after_coding": mean("mse_rounding_after_coding") / codes,
            "stored_stats_bytes_fp32": mean("stats_bytes_fp32"),
            "stored_stats_bytes_fp16": stats_bytes}  # fmt: skip


def table(result: dict[str, Any]) -> str:
    lines = [table_stored(result)]
    lines.append("")
    lines.append(f"{'material':<28} {'level':>5} {'read v2 s':>10} {'read v3 s':>10} "
                 f"{'v3/v2':>6} {'read+decode v2 s':>17} {'v3 s':>7} {'v3/v2':>6}")  # fmt: skip
    for t in result["timing"]:
        lines.append(f"{t['material']:<28} {t['level']:>5} {t['read_v2_s']:>10.4f} "
                     f"{t['read_v3_s']:>10.4f} {t['read_ratio']:>5.2f}x "
                     f"{t['read_decode_v2_s']:>17.3f} {t['read_decode_v3_s']:>7.3f} "
                     f"{t['read_decode_ratio']:>5.2f}x")  # fmt: skip
    f = result["fp16_stats_summary"]
    if f:
        lines.append("")
        lines.append(
            f"binary16 statistics at level {max(result['levels'])} (mean over "
            f"{len(result['fp16_stats'])} materials): the codes' MSE (linear RGB) with float32 "
            f"statistics {f['mse_codes_fp32_stats']:.4g}; rounded before coding (what encode "
            f"does) {f['mse_increase']:+.3g} ({100 * f['share_increase']:+.4f} % of it); rounded "
            f"after coding {f['mse_rounding_after_coding']:.3g} "
            f"({100 * f['share_rounding_after_coding']:.4f} %); stored statistics "
            f"{f['stored_stats_bytes_fp32']:,.0f} -> {f['stored_stats_bytes_fp16']:,.0f} bytes"
        )
    lines.append(f"({result['seconds']:.0f} s)")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--quick", action="store_true", help="seven 20x20 materials and a 40x40 one")
    p.add_argument("--timing", action="store_true",
                   help="only the read and read + decode timing of the large material (run it "
                   "on an idle machine)")
    p.add_argument("--repeat", type=int, default=3,
                   help="read + decode runs per schema, best kept (default 3)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    args = p.parse_args(argv)
    result = run(args.quick, timing_only=args.timing, repeat=args.repeat)
    if args.json:
        print(json.dumps(result, indent=2, default=float))
    else:
        print(table(result))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

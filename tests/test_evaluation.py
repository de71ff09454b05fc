"""The quality benchmark: PCA baseline accounting, levels, runner, report and CLI."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from sparsebtf.cli.main import main
from sparsebtf.errors import BTFInputError
from sparsebtf.evaluation.baselines import (
    PCAFit,
    allocate_ranks,
    fit_pca,
    pca_bytes,
    pca_rank_for_budget,
    pca_reconstruction,
)
from sparsebtf.evaluation.benchmark_set import BenchConfig, level_tau, paper_level_ratio
from sparsebtf.evaluation.report import regenerate
from sparsebtf.evaluation.runner import run_quality
from sparsebtf.evaluation.scoring import coded_mse_std, score_many

from .conftest import smooth_btf, tiny_model


def _matrix(btf, log: bool) -> np.ndarray:
    x = btf.to_array().astype(np.float64)
    x = x.reshape(btf.height * btf.width, -1, 3)
    return np.log(x + 1e-5) if log else x


def test_pca_bytes_and_rank_for_budget():
    t, a = 100 * 100, 151 * 151
    assert pca_bytes((2, 1, 0), t, a) == 2 * 3 * (t + a)
    assert pca_bytes(4, t, a) == 8 * (t + a)
    one = 2 * (t + a)
    assert pca_rank_for_budget(3 * one - 1, t, a) == 2
    assert pca_rank_for_budget(3 * one, t, a) == 3
    assert pca_rank_for_budget(one - 1, t, a) == 0
    # the chosen rank never exceeds its budget, and one more would
    for budget in (10_000, 507_100, 1_147_157, 2_566_270):
        r = pca_rank_for_budget(budget, t, a)
        assert pca_bytes(r, t, a) <= budget < pca_bytes(r + 1, t, a)
    with pytest.raises(BTFInputError):
        pca_rank_for_budget(-1, t, a)


@pytest.mark.parametrize("domain", ["log", "linear"])
def test_streamed_pca_matches_dense_svd(domain):
    btf = smooth_btf(3)
    # sketch as wide as the 64 texels: exact
    fit = fit_pca(btf, 4, domain=domain, oversample=60, power_iters=1, tile=3)
    x = _matrix(btf, domain == "log")
    for c in range(3):
        s = np.linalg.svd(x[:, :, c], compute_uv=False)
        np.testing.assert_allclose(fit.s[c], s[:4], rtol=1e-6)
    # a narrow sketch on this flat (noisy) spectrum still captures nearly the optimal energy
    narrow = fit_pca(btf, 4, domain=domain, oversample=6, power_iters=2, tile=3)
    for c in range(3):
        s = np.linalg.svd(x[:, :, c], compute_uv=False)
        assert np.sum(narrow.s[c] ** 2) >= 0.995 * np.sum(s[:4] ** 2)
    # rank-r reconstruction error equals the discarded energy (fp16 factors: close)
    rec = pca_reconstruction(fit, (4, 4, 4), btf)
    xr = _matrix(rec, False) if domain == "linear" else np.log(
        np.maximum(rec.to_array().astype(np.float64), 0) + 1e-5
    ).reshape(64, -1, 3)
    for c in range(3):
        s = np.linalg.svd(x[:, :, c], compute_uv=False)
        err = np.sum((x[:, :, c] - xr[:, :, c]) ** 2)
        assert err == pytest.approx(np.sum(s[4:] ** 2), rel=0.05, abs=1e-3)


def test_allocate_ranks_greedy_by_energy():
    s = np.array([[10.0, 1.0], [5.0, 4.0], [3.0, 0.5]])
    fit = PCAFit(np.zeros((3, 4, 2)), s, np.zeros((3, 5, 2)), "log", 2, 2)
    assert allocate_ranks(fit, 3) == (1, 2, 0)
    assert allocate_ranks(fit, 0) == (0, 0, 0)
    assert allocate_ranks(fit, 99) == (2, 2, 2)


def test_paper_levels():
    assert paper_level_ratio(32) == pytest.approx(2696.76, rel=1e-4)
    point = 2 * 10 * 10 * 151 * 151 * 3 / paper_level_ratio(32)
    assert level_tau(point, minimum=(256, 32, 32)) == (885, 64, 64)
    assert level_tau(1869.3, minimum=(256, 32, 32)) == (308, 32, 32)
    # decreasing ratios = increasing storage
    r = [paper_level_ratio(lv) for lv in (16, 32, 64, 128)]
    assert r == sorted(r, reverse=True)


def tiny_config() -> BenchConfig:
    return BenchConfig(
        name="tiny",
        classes=("carpet", "stone"),
        train_seeds=(1,),
        n_train=2,
        test_seeds=(12,),
        train_size=8,
        test_size=8,
        table5_materials=(("felt", 5),),
        table5_size=8,
        directions="tiny13",
        patch=4,
        n_dictionaries=2,
        tau_train=(8, 4, 4),
        sample=1.0,
        iters=3,
        tol=1e-2,
        levels=(16, 32),
        level_ratios=((16, 60.0), (32, 25.0)),
        curve_taus=((8, 4, 4), (40, 8, 8)),
        ssim_images=1,
        grid_levels=(32,),
        black_materials=(("metal", 12),),
        render_spp=2,
        render_size=16,
        speed_seconds=0.05,
        speed_batch=256,
    )


#: the methods of the tiny run (the neural ones have tests of their own: tests/test_neural.py)
TINY_METHODS = ("sparsebtf", "rate", "per_channel", "raw", "pca")


def tiny_bench(out, methods, config=None):
    """A quiet ``bench quality`` run of ``methods`` into ``out / "run"`` (materials cached in
    ``out / "cache"``; default: the tiny configuration); its results."""
    import os

    os.environ["SPARSEBTF_CACHE"] = str(out / "cache")
    os.environ["SPARSEBTF_PROGRESS"] = "0"
    return run_quality(out / "run", config or tiny_config(), log=lambda m: None,
                       methods=methods)  # fmt: skip


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("bench")
    return out / "run", tiny_bench(out, TINY_METHODS)


def test_bench_writes_json_tables_and_figures(tiny_run):
    out, result = tiny_run
    for name in ("results.json", "results.md", "table2.md", "table3.md", "table5.md",
                 "figure3.png", "quality_storage.png"):
        assert (out / name).stat().st_size > 0, name
    assert result["grids"] and all((out / g).exists() for g in result["grids"])
    data = json.loads((out / "results.json").read_text())
    methods = {r["method"] for r in data["rows"]}
    assert methods == {"sparsebtf", "rate", "per_channel", "raw", "pca_log", "pca_linear",
                       "release", "floored"}
    summary = data["summary"]
    for key in ("table2_processing", "table3_monotone", "table5_pca", "rate_control",
                "standardisation", "table4_check", "true_black"):
        assert "verdict" in summary[key], key
    md = (out / "results.md").read_text()
    assert "## Verdicts" in md and "figure3.png" in md and "## True black" in md


def test_test_classes_restrict_the_test_set_and_keep_its_rows(tiny_run, tmp_path, capsys):
    """``test_classes`` (``bench quality --test-classes``) tests some of the classes: the
    training is the whole run's, so each test material's rows are the whole run's."""
    from sparsebtf.evaluation.benchmark_set import CAPTURE_CLASSES

    cfg = replace(tiny_config(), test_classes=("stone",), table5_materials=(),
                  black_materials=(), render_spp=0, speed_seconds=0.0)  # fmt: skip
    assert cfg.test_set() == [("stone", 12)] and cfg.train_set() == tiny_config().train_set()
    glossy = replace(BenchConfig.quick().captured(), test_classes=("copper-rough", "brushed"))
    assert glossy.test_set() == [("brushed", 12), ("copper-rough", 12)]  # the classes' order
    assert {c for c, _ in glossy.train_set()} == set(CAPTURE_CLASSES) - {"copper-rough"}
    with pytest.raises(BTFInputError, match="test classes felt: not among"):
        replace(cfg, test_classes=("felt",)).test_set()
    result = tiny_bench(tmp_path, ("sparsebtf",), cfg)
    tests = [r for r in result["rows"] if r["set"] == "test"]
    assert {r["material"] for r in tests} == {"stone12"}
    whole = {(r["level"], r["material_bytes"]): r["mse_rgb"] for r in tiny_run[1]["rows"]
             if r["material"] == "stone12" and r["method"] == "sparsebtf"}
    assert len(whole) > 2  # the levels and Figure 3's curve points
    assert {(r["level"], r["material_bytes"]): r["mse_rgb"] for r in tests} == whole
    md = (tmp_path / "run" / "results.md").read_text()
    assert "--test-classes stone" in md and "1 unseen test materials (classes stone)" in md
    # the command line: a class not in the source, or one named twice, is one clear line
    for bad, msg in (("carpet,copper", "test classes copper: not among"),
                     ("stone,stone", "twice")):
        assert main(["bench", "quality", "--quick", "--test-classes", bad,
                     "--out", str(tmp_path / "x")]) == 2  # fmt: skip
        err = capsys.readouterr().err
        assert msg in err and "Traceback" not in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "x").exists()


def test_bench_renders_figure8_and_measures_decode_speed(tiny_run):
    """Figure 8 (each method's level-32 reconstruction rendered beside the reference) and
    Table 1's decode speed land in results.json and results.md."""
    out, result = tiny_run
    f8 = result["figure8"]
    assert f8["level"] == 32 and f8["material"] == result["rows"][0]["material"]
    labels = set(f8["methods"])
    assert {"SparseBTF(32)", "[MHU19] (raw RGB)(32)"} <= labels
    for r in f8["methods"].values():
        assert r["image_mse"] > 0 and r["flip"] > 0
        # each method's PNG by its name in the run's figure8 folder: a results.json copied
        # into docs names no machine's folder
        assert "/" not in r["png"] and (out / "figure8" / r["png"]).exists()
    assert str(out) not in json.dumps(result, default=str)
    assert (out / "figure8" / "figure8.png").stat().st_size > 0
    speed = result["decode_speed"]["methods"]
    assert set(speed) == labels
    assert all(r["queries_per_second_1"] > 0 for r in speed.values())
    md = (out / "results.md").read_text()
    assert "## Figure 8 shape" in md and "figure8/figure8.png" in md
    assert "## Decode speed" in md
    # every method's training budget beside the comparison
    budgets = md[md.index("Training budgets"):]
    assert all(run["label"] in budgets for run in result["method_runs"].values())


def test_bench_meets_true_black(tiny_run):
    """The benchmark codes a material with exact zeros three ways, each scored against the
    unfloored material, with the largest decoded value and the error concentration."""
    _, result = tiny_run
    black = [r for r in result["rows"] if r["set"] == "black"]
    assert {r["method"] for r in black} == {"sparsebtf", "release", "floored"}
    assert {r["material"] for r in black} == {"metal12+black"}
    for r in black:
        # the bound (kept rounded up to 1/32 in the log), whatever the offset
        assert r["max_decoded"] <= r["reference_max"] * 1.033
        assert 0 < r["top_error_share"] <= 1
    offsets = {r["method"]: r["log_offset"] for r in black}
    assert offsets["release"] == offsets["floored"] == 1e-5 < offsets["sparsebtf"]
    entry = result["summary"]["true_black"]["per_material"]["metal12+black"]
    assert len(entry["sparsebtf"]["mse"]) == 2 and "monotone" in entry


def test_bench_equal_storage(tiny_run):
    _, result = tiny_run
    rows = result["rows"]
    for r in rows:
        if r["method"] == "rate":
            fixed = next(x for x in rows if x["method"] == "sparsebtf"
                         and x["material"] == r["material"] and x["level"] == r["level"])
            assert r["target_bytes"] == fixed["material_bytes"]
            assert abs(r["material_bytes"] - r["target_bytes"]) <= 0.01 * r["target_bytes"]
        if r["method"].startswith("pca"):
            assert r["material_bytes"] <= r["budget_bytes"]
            t, a = 8 * 8, 13 * 13
            assert r["material_bytes"] == pca_bytes(tuple(r["ranks"]), t, a)
    # every sparse method at a level spends (about) the level's per-material budget
    for lv, ratio in ((16, 60.0), (32, 25.0)):
        for m in ("sparsebtf", "per_channel", "raw"):
            for r in (x for x in rows if x["method"] == m and x["level"] == lv):
                assert r["ratio_per_material"] == pytest.approx(ratio, rel=0.12)


def test_bench_report_regenerates_docs(tiny_run, tmp_path):
    out, _ = tiny_run
    target = regenerate(out, tmp_path / "docs")
    text = target.read_text()
    assert "results/figure3.png" in text and "bench report" in text
    assert (tmp_path / "docs" / "results" / "figure3.png").exists()


def test_cli_bench_quality_tiny(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(BenchConfig, "quick", classmethod(
        lambda cls: replace(tiny_config(), with_per_channel=False, pca_domains=("log",))))
    rc = main(["bench", "quality", "--quick", "--out", str(tmp_path / "q"), "--json",
               "--docs", str(tmp_path / "docs"), "--methods", ",".join(TINY_METHODS)])
    assert rc == 0
    out = capsys.readouterr().out
    assert "table3_monotone" in out
    assert (tmp_path / "docs" / "results.md").exists()
    rc = main(["bench", "quality", "--quick", "--out", str(tmp_path / "q2"),
               "--materials", "synth:wood:7:1:tiny13"])  # size 7: not a multiple of the patch
    assert rc == 2
    assert "patch" in capsys.readouterr().err


def test_fast_scores_equal_compare():
    """score_many (one pass, log domain, Parseval) gives compare()'s numbers."""
    from sparsebtf.codec import encode_levels, train
    from sparsebtf.metrics import compare
    from sparsebtf.runtime import coded_btf_view

    model = tiny_model()
    btf = smooth_btf(7)
    coded = encode_levels(btf, model, [(16, 4, 4), (120, 30, 30)], eps=0.0, progress=False)
    raw_model = train([smooth_btf(s) for s in range(3)], n_dictionaries=2, tau_train=(8, 8, 8),
                      patch=4, sample=1.0, max_iter=1, progress=False,
                      preprocessing="identity")
    raw = encode_levels(btf, raw_model, [(20, 20, 20)], eps=0.0, progress=False)[0]
    fit = fit_pca(btf, 3, domain="log", oversample=60, power_iters=1, tile=3)
    recs = [coded_btf_view(c) for c in coded] + [coded_btf_view(raw),
                                                 pca_reconstruction(fit, (2, 1, 1), btf)]
    stats = [c.stats for c in coded] + [None, None]
    fast = score_many(btf, recs, ssim_images=3, tile=4, progress=False)
    for rec, st, f in zip(recs, stats, fast, strict=True):
        slow = compare(btf, rec, stats=st, ssim_images=3, tile=4, progress=False)
        for key in ("mse_rgb", "mse_log", "mse_display", "psnr_rgb", "ssim", "peak",
                    "reference_max", "max_decoded", "top_error_share"):
            assert f[key] == pytest.approx(slow[key], rel=1e-5), key
        assert f["mse_display"] > 0
        if st is None:
            assert "mse_std" not in f
        else:
            # Parseval from the codes = the decoded standardised-domain error before the
            # bound; the bound only ever lowers it
            free = replace(rec.coded, stats=replace(st, bound=None))
            unclamped = compare(btf, coded_btf_view(free), stats=free.stats, ssim_images=0,
                                tile=4, progress=False)
            assert f["mse_std"] == pytest.approx(unclamped["mse_std"], rel=1e-4)
            assert slow["mse_std"] <= f["mse_std"] * (1 + 1e-4)
    # and the coded-domain error is the one the encoder stored
    c = coded[0]
    assert coded_mse_std(c) == pytest.approx(
        np.mean([c.codes[ch].errors.mean() for ch in c.channels]), rel=1e-12)
    with pytest.raises(BTFInputError, match="cannot compare"):
        score_many(btf, [smooth_btf(1, size=4)])


def test_mse_display_is_the_paper_display_mapping():
    """mse_display of compare and score_many = a direct NumPy computation of
    mean((clip(1.3·max(a, 0)^(1/1.8), 0, 1) − clip(1.3·max(b, 0)^(1/1.8), 0, 1))²), on a
    reconstruction with negative values, values above white and one firework."""
    from sparsebtf.data.btf import ArrayBTF
    from sparsebtf.metrics import compare

    ref = smooth_btf(4)
    rng = np.random.default_rng(5)
    rec = ref.data * rng.uniform(0.6, 1.4, ref.data.shape)
    rec[0, 0, 0, 0] = -0.2
    rec[3, 5, 7, 2] = 1e3  # a firework: the linear MSE is all its; on display it is white
    rec = ArrayBTF(rec.astype(np.float32), ref.lights, ref.views, name="noisy")

    def shown(x):
        return np.clip(1.3 * np.maximum(x.astype(np.float64), 0) ** (1 / 1.8), 0, 1)

    direct = float(np.mean((shown(ref.data) - shown(rec.data)) ** 2))
    assert 1e-4 < direct < 0.1
    slow = compare(ref, rec, ssim_images=0, tile=4, progress=False)
    fast = score_many(ref, [rec], ssim_images=0, tile=4, progress=False)[0]
    assert slow["mse_display"] == pytest.approx(direct, rel=1e-5)
    assert fast["mse_display"] == pytest.approx(direct, rel=1e-5)
    # the firework carries the linear error, not the displayed one
    assert slow["top_error_share"] > 0.99 and slow["mse_rgb"] > 1e3 * slow["mse_display"]


def test_bench_trains_to_convergence(tiny_run):
    _, result = tiny_run
    for info in result["models"].values():
        for t in info["training"].values():
            assert 1 <= t["n_iter"] <= 3
            assert t["passes"][-1] == "full"
            obj = t["objective"]
            if t["n_iter"] < 3:  # stopped on the tolerance
                assert (obj[-2] - obj[-1]) / obj[-2] < 1e-2
    md = (tiny_run[0] / "results.md").read_text()
    assert "trained until an iteration lowered the objective by less than 0.01" in md


def test_report_notes_how_verdicts_moved(tiny_run, tmp_path):
    out, result = tiny_run
    docs = tmp_path / "docs"
    # an earlier run held in docs: a copy of this one with other figures and verdicts
    old = json.loads((out / "results.json").read_text())
    old["created"] = "2020-01-01T00:00:00Z"
    old["summary"]["table2_processing"]["ratio_geomean"] = 1.24
    old["summary"]["table5_pca"]["verdict"] = "an older verdict"
    (docs / "results").mkdir(parents=True)
    (docs / "results" / "results.json").write_text(json.dumps(old))
    text = regenerate(out, docs).read_text()
    assert "moved from the previous run" in text
    row = next(line for line in text.splitlines() if line.startswith("| BTF-specific"))
    now = result["summary"]["table2_processing"]["ratio_geomean"]
    assert f"1.24x → {now:.2f}x" in row
    assert "compares with the previous run (2020-01-01T00:00:00Z, configuration tiny" in text
    t5 = next(line for line in text.splitlines() if "twice its storage" in line)
    assert "was **an older verdict**" in t5
    # the docs copy keeps the comparison: regenerating it in place writes the same notes
    held = json.loads((docs / "results" / "results.json").read_text())
    assert held["previous"]["created"] == "2020-01-01T00:00:00Z"
    again = regenerate(docs / "results", docs).read_text()
    assert f"1.24x → {now:.2f}x" in again
    # an explicit --previous wins; a bad one is one clear error
    rc = main(["bench", "report", str(out), "--docs", str(docs), "--previous",
               str(docs / "results" / "results.json")])
    assert rc == 0
    assert main(["bench", "report", str(out), "--docs", str(docs), "--previous",
                 str(tmp_path / "missing.json")]) == 2


def test_report_sets_captured_verdicts_beside_the_synthetic_ones(tiny_run, tmp_path):
    """A captured run's verdicts go beside the synthetic run's in results.md (found in
    DOCS/capture/results, or named by --captured), with what differs and Table 2's gain
    against each material's dynamic range (largest / median, the medians the runner records)."""
    from sparsebtf.evaluation.captured import range_trend

    out, result = tiny_run
    tests = sorted({r["material"] for r in result["rows"] if r["set"] == "test"})
    values = result["material_values"]
    assert set(tests) <= set(values) and all(values[m]["median"] > 0 for m in tests)
    cap = json.loads((out / "results.json").read_text())
    cap["config"].update(source="capture", classes=["woven", "metal"], spp=4)
    cap["created"] = "2026-01-02T00:00:00Z"
    cap["summary"]["table5_pca"]["verdict"] = "a captured verdict"
    capdir = tmp_path / "docs" / "capture" / "results"
    capdir.mkdir(parents=True)
    (capdir / "results.json").write_text(json.dumps(cap))
    (capdir.parent / "results.md").write_text("# captured\n")
    text = regenerate(out, tmp_path / "docs").read_text()
    assert "## On captured materials" in text and "(capture/results.md)" in text
    t5 = next(line for line in text.splitlines()
              if "twice its storage" in line and "captured verdict" in line)
    assert t5.endswith("| **verdict differs** |")
    t3 = next(line for line in text.splitlines()
              if line.startswith("| the error falls") and "same verdict" in line)
    assert t3.count("**") == 4
    for m in tests:  # one dynamic-range row per material and source
        assert sum(line.startswith(f"| {m} | ") for line in text.splitlines()) == 2
    # the trend rule: Spearman's rho of the dynamic range against the Table-2 ratio
    rows = [{"range": 10.0 ** k, "table2_ratio": 1 + k} for k in range(5)]
    assert range_trend(rows)["verdict"] == "the gain grows with the dynamic range"
    assert range_trend(rows[::-1][:1] + rows[1:3])["verdict"] == "too few materials to tell"
    flipped = [{**r, "table2_ratio": 5 - r["table2_ratio"]} for r in rows]
    assert range_trend(flipped)["verdict"] == "the gain falls as the dynamic range grows"
    # --captured names a run; a synthetic run there is one clear error
    assert main(["bench", "report", str(out), "--docs", str(tmp_path / "d2"),
                 "--captured", str(capdir)]) == 0
    assert "## On captured materials" in (tmp_path / "d2" / "results.md").read_text()
    assert main(["bench", "report", str(out), "--docs", str(tmp_path / "d3"),
                 "--captured", str(out)]) == 2
    # a captured run's own results.md has no such section
    assert "## On captured" not in regenerate(capdir, tmp_path / "d4").read_text()


def _comparable(result, folder):
    """A results object without what differs between any two runs: measured times and speeds,
    the date, the resumptions, the output folder."""

    def strip(v):
        if isinstance(v, dict):
            return {k: strip(x) for k, x in v.items() if not (
                "second" in str(k) or str(k).startswith("calls_") or k in ("created", "resumed"))}
        return [strip(x) for x in v] if isinstance(v, list) else v

    text = json.dumps(strip(result), default=str).replace(str(folder), "OUT")
    return json.loads(text)


def test_interrupted_run_resumes_to_the_uninterrupted_results(tiny_run, tmp_path, monkeypatch,
                                                              capsys):  # fmt: skip
    from sparsebtf.errors import SparseBTFError
    from sparsebtf.evaluation import resume as store
    from sparsebtf.evaluation.methods.base import Method

    _, full = tiny_run
    run = tmp_path / "run"
    saved = store.Progress.save_material

    def interrupt(self, index, *a, **k):  # the first material's checkpoint, then a crash
        saved(self, index, *a, **k)
        raise KeyboardInterrupt

    monkeypatch.setattr(store.Progress, "save_material", interrupt)
    with pytest.raises(KeyboardInterrupt):
        run_quality(run, tiny_config(), log=lambda m: None, methods=TINY_METHODS)
    monkeypatch.undo()
    partial = run / "partial"
    assert sorted(p.name for p in partial.iterdir()) == ["material-000.pkl", "methods.pkl",
                                                         "run.json"]  # fmt: skip
    # checkpoints need --resume; --resume needs the same settings
    with pytest.raises(SparseBTFError, match="add --resume"):
        run_quality(run, tiny_config(), log=lambda m: None, methods=TINY_METHODS)
    with pytest.raises(SparseBTFError, match=r"other seed, config\.table5_materials"):
        run_quality(run, tiny_config(), seed=1, log=lambda m: None, methods=TINY_METHODS,
                    resume=True)  # fmt: skip
    assert main(["bench", "quality", "--out", str(tmp_path / "none"), "--resume"]) == 2
    assert "no checkpoint" in capsys.readouterr().err
    # resumed: no method fitted again, the first material not coded again
    monkeypatch.setattr(Method, "fit", lambda *a: pytest.fail("fitted again"))
    lines: list[str] = []
    result = run_quality(run, tiny_config(), log=lines.append, methods=TINY_METHODS,
                         resume=True)  # fmt: skip
    assert any("carpet12: " in m and "(checkpoint)" in m for m in lines)
    assert not any("carpet12: metrics" in m for m in lines)
    assert result["resumed"] == 1 and full["resumed"] == 0
    assert not partial.exists()  # done: the checkpoints are removed
    assert result["rows"] == full["rows"]
    assert _comparable(result, run) == _comparable(full, tiny_run[0])
    written = json.loads((run / "results.json").read_text())
    assert written["resumed"] == 1 and written["timings_seconds"]["train_sparsebtf"] > 0


def test_bench_quality_codes_and_reads_the_verdicts_per_objective(tmp_path, monkeypatch, capsys):
    """``objectives=("log", "linear")``: the reference and rate control coded under both (the
    linear rows under ``sparsebtf-linear`` etc. with the same model), every SparseBTF row
    records its objective, the verdicts are read per objective, results.md says so."""
    monkeypatch.setenv("SPARSEBTF_CACHE", str(tmp_path / "cache"))
    monkeypatch.setenv("SPARSEBTF_PROGRESS", "0")
    cfg = replace(tiny_config(), objectives=("log", "linear"), render_spp=0, speed_seconds=0,
                  with_per_channel=False, curve_taus=())
    result = run_quality(tmp_path / "run", cfg, log=lambda m: None,
                         methods=("sparsebtf", "rate", "raw", "pca"))
    assert list(result["config"]["objectives"]) == ["log", "linear"]
    assert json.loads((tmp_path / "run" / "results.json").read_text())["config"][
        "objectives"] == ["log", "linear"]
    rows = result["rows"]
    by = {}
    for r in rows:
        by.setdefault(r["method"], []).append(r)
    for name in ("sparsebtf", "rate", "release", "floored"):
        assert {r["objective"] for r in by[name]} == {"log"}, name
        assert {r["objective"] for r in by[f"{name}-linear"]} == {"linear"}, name
        assert len(by[f"{name}-linear"]) == len(by[name])
    assert {r["objective"] for r in by["raw"]} == {"log"}  # raw RGB: its rule is linear already
    # the objective reached the encodes: some linear code differs from the log one
    key = lambda r: (r["material"], r["set"], r["level"])  # noqa: E731
    log_mse = {key(r): r["mse_rgb"] for r in by["sparsebtf"]}
    assert any(r["mse_rgb"] != log_mse[key(r)] for r in by["sparsebtf-linear"])
    assert set(result["models"]) == {"sparsebtf", "raw"}  # the variants train nothing
    summary = result["summary"]
    assert summary["objective"] == "log" and list(summary["by_objective"]) == ["log", "linear"]
    for o in ("log", "linear"):
        assert {"table2_processing", "table3_monotone", "table5_pca", "true_black",
                "rate_control"} <= set(summary["by_objective"][o])  # fmt: skip
    assert summary["by_objective"]["log"]["table5_pca"] == summary["table5_pca"]
    lin_t5 = summary["by_objective"]["linear"]["table5_pca"]["per_material"]
    assert all(v["sparsebtf"] == next(r["mse_rgb"] for r in by["sparsebtf-linear"]
                                      if r["material"] == m and r["set"] == "table5")
               for m, v in lin_t5.items())  # fmt: skip
    md = (tmp_path / "run" / "results.md").read_text()
    assert "## Verdicts per coding objective" in md and "--objective log,linear" in md
    assert "Coding objective of every SparseBTF encode: log; also linear" in md
    # the command line: several objectives, or one clear line
    from sparsebtf.cli.bench import _objectives

    assert _objectives("log, display") == ("log", "display")
    for bad, msg in (("lin", "unknown coding objective 'lin'"), ("log,log", "twice")):
        assert main(["bench", "quality", "--quick", "--objective", bad,
                     "--out", str(tmp_path / "x")]) == 2  # fmt: skip
        err = capsys.readouterr().err
        assert msg in err and "Traceback" not in err and len(err.strip().splitlines()) == 1

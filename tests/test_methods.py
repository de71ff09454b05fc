"""The benchmark's methods: selection (--methods, --method), a user's own method through the
runner and the report, SparseBTF's rows against the public codec, the Table-3 verdicts."""

from __future__ import annotations

import json
import re
import shutil
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from sparsebtf.cli.main import main
from sparsebtf.data.btf import FunctionBTF
from sparsebtf.errors import BTFInputError
from sparsebtf.evaluation.benchmark_set import BenchConfig
from sparsebtf.evaluation.methods import (
    PAPER,
    PER_MATERIAL,
    Coding,
    Method,
    method_class,
    register_method,
    selection,
)
from sparsebtf.evaluation.methods.selection import parse_methods, resolve_methods

from .test_evaluation import tiny_config

DOCS = Path(__file__).resolve().parents[1] / "docs"


class FlatMethod(Method):
    """Test method: every texel is the material's mean value per colour (3 binary16 values),
    coded under both matchings; its info says which budget it saw."""

    name = "flat_test"
    label = "Flat (test)"
    matchings = (PAPER, PER_MATERIAL)

    def code(self, btf, budgets):
        mean = np.zeros(3)
        for v in range(len(btf.views)):
            mean += btf.view_block(v).astype(np.float64).mean(axis=(0, 1, 2))
        mean = (mean / len(btf.views)).astype(np.float16).astype(np.float32)
        shape = (btf.height, btf.width, len(btf.lights), 3)
        rec = FunctionBTF((btf.height, btf.width), btf.lights, btf.views,
                          lambda v: np.broadcast_to(mean, shape))  # fmt: skip
        return [Coding(rec, 6, info={"seen_bytes": b.material_bytes, "seen": b.matching})
                for b in budgets]  # fmt: skip


# -- selection --------------------------------------------------------------------------------
def test_parse_methods_expands_groups_in_order():
    assert parse_methods("pca,sparsebtf") == ["pca_log", "pca_linear", "sparsebtf"]
    assert parse_methods(" mhu19 , raw,rate") == ["raw", "rate"]
    for bad in ("bogus", "sparsebtf,pca_cubic", ","):
        with pytest.raises(BTFInputError) as e:
            parse_methods(bad)
        assert "--methods" in str(e.value) and "pca_linear" in str(e.value)


def test_cli_unknown_method_is_one_line_listing_the_choices(tmp_path, monkeypatch, capsys):
    import sparsebtf.evaluation.runner as runner

    monkeypatch.setattr(runner, "run_quality", lambda *a, **k: pytest.fail("ran"))
    assert main(["bench", "quality", "--methods", "sparsebtf,bogus", "--out",
                 str(tmp_path / "q")]) == 2  # fmt: skip
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "'bogus'" in err and "rgjw20+ft" in err and "mhu19" in err
    for spec, want in (("no_such_module_xyz:Foo", "cannot import"),
                       ("tests.test_methods:Nothing", "has no Nothing"),
                       ("tests.test_methods:tiny_config", "not a subclass"),
                       ("flat_test", "package.module:Class")):  # fmt: skip
        assert main(["bench", "quality", "--method", spec, "--out", str(tmp_path / "q")]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and want in err, err


def test_cli_passes_methods_and_notes_missing_torch(tmp_path, monkeypatch, capsys):
    import sparsebtf.evaluation.runner as runner

    seen = {}
    monkeypatch.setattr(runner, "run_quality",
                        lambda out, cfg, **kw: seen.update(kw) or {"summary": {}})  # fmt: skip
    monkeypatch.setattr(selection, "torch_available", lambda: False)
    assert main(["bench", "quality", "--quick", "--out", str(tmp_path / "q"),
                 "--method", "tests.test_methods:FlatMethod"]) == 0  # fmt: skip
    err = capsys.readouterr().err
    assert seen["methods"] == [*selection.BASELINE_METHODS, "tests.test_methods:FlatMethod"]
    assert err.count("sparsebtf: note:") == 1 and 'pip install -e ".[neural]"' in err
    assert main(["bench", "quality", "--quick", "--out", str(tmp_path / "q"),
                 "--methods", "raw,pca"]) == 0  # fmt: skip
    assert seen["methods"] == ["raw", "pca_log", "pca_linear"]
    assert "note" not in capsys.readouterr().err  # named methods: nothing left out
    monkeypatch.setattr(selection, "torch_available", lambda: True)
    monkeypatch.setattr(selection, "_neural_present", lambda: True)
    assert selection.default_methods() == [*selection.BASELINE_METHODS,
                                           *selection.NEURAL_METHODS]  # fmt: skip


def test_resolve_puts_the_reference_first_and_config_flags_drop_methods():
    cfg = replace(tiny_config(), with_raw=False, with_rate_control=False, pca_domains=("log",))
    names = [c.name for c in resolve_methods(["pca", "raw", "rate", "per_channel", FlatMethod],
                                             cfg)]  # fmt: skip
    assert names == ["sparsebtf", "pca_log", "per_channel", "flat_test"]
    assert [c.name for c in resolve_methods(None, tiny_config())][:1] == ["sparsebtf"]

    class Clash(FlatMethod):
        pass

    with pytest.raises(BTFInputError, match="taken"):
        resolve_methods([FlatMethod, Clash], cfg)


class FakeRGJW20(FlatMethod):
    """Stands in for RGJW20 (the neural methods are another module's): its rows feed the
    Table-3 verdicts and the Figure-5 image."""

    name = "rgjw20"
    label = "RGJW20 (test)"


# -- a run with a user's method ------------------------------------------------------------------
@pytest.fixture(scope="module")
def flat_run(tmp_path_factory):
    import os

    from sparsebtf.evaluation.runner import run_quality

    out = tmp_path_factory.mktemp("methods")
    os.environ["SPARSEBTF_CACHE"] = str(out / "cache")
    os.environ["SPARSEBTF_PROGRESS"] = "0"
    register_method("flat_test", FlatMethod)
    cfg = replace(tiny_config(), with_per_channel=False, with_raw=False,
                  with_rate_control=False, pca_domains=("log",))  # fmt: skip
    result = run_quality(out / "run", cfg, log=lambda m: None,
                         methods=["sparsebtf", "flat_test", FakeRGJW20])  # fmt: skip
    return out / "run", result, cfg


def test_registered_method_has_rows_per_matching_and_appears_in_the_report(flat_run):
    out, _, _ = flat_run
    assert method_class("flat_test") is FlatMethod
    data = json.loads((out / "results.json").read_text())
    assert {r["method"] for r in data["rows"]} == {"sparsebtf", "flat_test", "rgjw20",
                                                   "release", "floored"}  # fmt: skip
    flat = [r for r in data["rows"] if r["method"] == "flat_test"]
    assert {r["set"] for r in flat} == {"test"}  # sets = ("test",): not on Table 5
    ref = {(r["material"], r["level"]): r for r in data["rows"]
           if r["method"] == "sparsebtf" and r["set"] == "test" and r["level"] is not None}
    assert len(flat) == 2 * len(ref)  # every level under both matchings
    for r in flat:
        want = (2 * r["level"] * 8 * 8 if r["matching"] == PAPER
                else ref[(r["material"], r["level"])]["material_bytes"])  # fmt: skip
        assert r["budget_bytes"] == r["seen_bytes"] == want and r["seen"] == r["matching"]
        assert r["material_bytes"] == 6 and r["mse_rgb"] > 0 and "mse_display" in r
    run = data["method_runs"]["flat_test"]
    assert run["label"] == "Flat (test)" and run["scope"] == "per_material"
    assert run["shared_bytes"] == 0 and run["matchings"] == [PAPER, PER_MATERIAL]
    assert data["method_runs"]["sparsebtf"]["reference"] is True
    assert data["method_runs"]["sparsebtf"]["shared_bytes"] == \
        data["models"]["sparsebtf"]["bytes_dictionaries"] > 0
    md = (out / "results.md").read_text()
    section = md[md.index("## Table 3: SparseBTF against"):md.index("## Table 5")]
    assert "**Matching: the paper's" in section and "**Matching: per material" in section
    assert section.count("| Flat (test) (16) |") == 2  # once per matching
    assert "Flat (test)" in (out / "table2.md").read_text()
    s = data["summary"]
    vs = s["table3_vs_rgjw20"]
    assert vs["matching"] == PAPER and vs["cells_won"].endswith("/4")  # 2 levels x 2 materials
    assert vs["verdict"] in ("supported", "not supported")
    assert s["table3_rgjw20_stalls"]["verdict"] == "not measured"  # levels 16, 32 only
    assert s["table3_rjgw19_lowest"]["verdict"] == "not measured"
    assert data["figure5"] == ["figure5_carpet12.png"] and (out / "figure5_carpet12.png").exists()
    assert "figure5_carpet12.png" in md and "| RGJW20 (test) (32) |" in section
    assert "table2_metrics" not in s  # no [MHU19] in this run
    assert {"table3_monotone", "true_black"} <= set(s)
    assert "table5_pca" not in s  # no PCA in this run: nothing to compare Table 5 with


def test_sparsebtf_rows_equal_the_public_codec(flat_run):
    """The reference's rows of a run, recomputed with train + encode_levels + score_many."""
    from sparsebtf.codec import encode_levels, train
    from sparsebtf.evaluation.benchmark_set import level_tau
    from sparsebtf.evaluation.scoring import score_many
    from sparsebtf.runtime import coded_btf_view
    from sparsebtf.storage.accounting import storage_report

    _, result, cfg = flat_run
    train_btfs = [cfg.material(c, cfg.train_size, s) for c, s in cfg.train_set()]
    model = train(train_btfs, n_dictionaries=cfg.n_dictionaries, patch=cfg.patch,
                  sample=cfg.sample, max_iter=cfg.iters, tol=cfg.tol, seed=0,
                  tau_train=cfg.tau_train, std_mode="shared")  # fmt: skip
    assert model.content_hash == result["models"]["sparsebtf"]["content_hash"]
    ratios = cfg.ratios()
    checked = 0
    for cls, seed in cfg.test_set():
        btf = cfg.material(cls, cfg.test_size, seed)
        n_pts = (btf.height // cfg.patch) * (btf.width // cfg.patch)
        taus = [level_tau(2 * btf.n_values / ratios[lv] / n_pts, minimum=cfg.tau_train)
                for lv in cfg.levels]  # fmt: skip
        taus += [tuple(t) for t in cfg.curve_taus if tuple(t) not in taus]
        coded = encode_levels(btf, model, taus, eps=0.0, allow_below_training=True,
                              log_offset=cfg.log_offset, candidates=cfg.candidates)
        scores = score_many(btf, [coded_btf_view(c) for c in coded],
                            ssim_images=cfg.ssim_images, tile=2 * cfg.patch, progress=False)
        rows = [r for r in result["rows"] if r["method"] == "sparsebtf" and r["set"] == "test"
                and r["material"] == f"{cls}{seed:02d}"]  # fmt: skip
        assert [r["tau"] for r in rows] == [list(t) for t in taus]
        for r, c, s in zip(rows, coded, scores, strict=True):
            rep = storage_report(c, model)
            assert r["material_bytes"] == rep["bytes_coefficients"] + rep["bytes_membership_counts"]
            for key in ("mse_rgb", "mse_log", "mse_std", "psnr_rgb", "ssim", "max_decoded"):
                assert r[key] == float(s[key]), key  # exactly, not approximately
            checked += 1
    # every reference row of the test set: the levels and the curve points
    assert checked == sum(r["method"] == "sparsebtf" and r["set"] == "test"
                          for r in result["rows"]) > len(cfg.test_set()) * len(cfg.levels)


# -- the documented example ------------------------------------------------------------------
def _doc_example() -> str:
    text = (DOCS / "benchmarks.md").read_text()
    section = text[text.index("Your own method"):]
    return re.search(r"```python\n(.*?)```", section, re.S).group(1)


def test_the_documented_method_runs_through_the_cli(tmp_path, monkeypatch):
    (tmp_path / "mymethods_doc.py").write_text(_doc_example())
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setenv("SPARSEBTF_CACHE", str(tmp_path / "cache"))
    monkeypatch.setattr(BenchConfig, "quick", classmethod(lambda cls: replace(
        tiny_config(), with_per_channel=False, with_rate_control=False, pca_domains=("log",),
        black_materials=())))  # fmt: skip
    out = tmp_path / "run"
    assert main(["bench", "quality", "--quick", "--methods", "sparsebtf,raw", "--method",
                 "mymethods_doc:MeanABRDF", "--out", str(out)]) == 0  # fmt: skip
    data = json.loads((out / "results.json").read_text())
    rows = [r for r in data["rows"] if r["method"] == "mean_abrdf"]
    assert rows and all(r["mse_rgb"] is not None and "within_budget" in r for r in rows)
    # 2 B per value: the mean ABRDF (13 x 13 x 3) and a scale per texel (8 x 8 x 3)
    assert {r["material_bytes"] for r in rows} == {2 * (13 * 13 * 3 + 8 * 8 * 3)}
    label = "Mean ABRDF x scale"
    assert data["methods"]["mean_abrdf"] == label
    assert label in (out / "table2.md").read_text() and label in (out / "results.md").read_text()


# -- the Table-3 verdicts on the paper's own Table 3 -----------------------------------------------
PAPER_TABLE3 = {  # MSE x 1e-4 (the paper's Table 3: Carpet, Fabric, Felt, Leather, Stone,
    # Wallpaper, Wood 12)
    ("rjgw19", 16): (1.5, 0.8, 1.5, 14, 1.5, 1.1, 0.9),
    ("rgjw20", 16): (3.3, 6.7, 2.7, 101, 4.9, 1.9, 4.5),
    ("sparsebtf", 16): (1.8, 3.7, 1.6, 83, 6.0, 2.2, 2.1),
    ("rjgw19", 32): (0.9, 0.5, 1.0, 11, 1.1, 0.9, 0.8),
    ("rgjw20", 32): (2.4, 4.5, 2.0, 90, 3.7, 1.5, 4.0),
    ("sparsebtf", 32): (1.0, 3.0, 1.0, 71, 4.3, 1.6, 1.6),
    ("rjgw19", 64): (0.5, 0.4, 0.7, 11, 0.9, 0.7, 0.7),
    ("rgjw20", 64): (2.2, 4.0, 1.8, 98, 3.7, 1.5, 4.1),
    ("sparsebtf", 64): (0.7, 2.7, 0.7, 47, 3.2, 1.2, 1.2),
    ("rjgw19", 128): (0.5, 0.4, 0.6, 10, 0.9, 0.7, 0.7),
    ("rgjw20", 128): (2.2, 4.3, 1.8, 96, 3.7, 1.4, 4.5),
    ("sparsebtf", 128): (0.5, 2.3, 0.5, 32, 2.4, 1.0, 1.0),
}


def _paper_result(methods=("sparsebtf", "rgjw20", "rjgw19")) -> dict:
    mats = ["carpet12", "fabric12", "felt12", "leather12", "stone12", "wallpaper12", "wood12"]
    rows = []
    for (m, lv), vals in PAPER_TABLE3.items():
        if m not in methods:
            continue
        for mat, v in zip(mats, vals, strict=True):
            row = {"material": mat, "set": "test", "method": m, "level": lv, "mse_rgb": v * 1e-4}
            if m != "sparsebtf":
                row.update(matching=PAPER, budget_factor=1)
            rows.append(row)
    return {"config": {"levels": [16, 32, 64, 128]}, "rows": rows,
            "methods": {"sparsebtf": "SparseBTF", "rgjw20": "RGJW20", "rjgw19": "RJGW19"}}


def test_table3_verdicts_read_the_papers_table_as_the_paper_does():
    from sparsebtf.evaluation.claims3 import summarise_table3, table3_comparison

    s = summarise_table3(_paper_result(), 32)
    assert s["table3_vs_rgjw20"]["cells_won"] == "24/28"
    assert s["table3_vs_rgjw20"]["verdict"] == "supported"
    stall = s["table3_rgjw20_stalls"]
    assert stall["sparsebtf_falls"] == "7/7" and stall["verdict"] == "supported"
    assert stall["rgjw20_gain_geomean"] == pytest.approx(1.018, abs=1e-3)
    assert stall["sparsebtf_gain_geomean"] == pytest.approx(1.76, abs=0.01)
    assert s["table3_rjgw19_lowest"]["cells_lowest"] == "27/28"  # felt12 at 128: 0.6 > 0.5
    assert s["table3_rjgw19_lowest"]["verdict"] == "supported"
    text = table3_comparison(_paper_result())
    assert "**Matching: the paper's" in text and "| RGJW20 (128) | 2.2 | 4.3 |" in text
    assert "per material" not in text  # nothing was coded per material
    # an absent method is "not measured", never a verdict
    s = summarise_table3(_paper_result(("sparsebtf", "rgjw20")), 32)
    assert s["table3_rjgw19_lowest"]["verdict"] == "not measured"
    assert s["table3_vs_rgjw20"]["verdict"] == "supported"
    s = summarise_table3(_paper_result(("sparsebtf",)), 32)
    assert {v["verdict"] for v in s.values()} == {"not measured"}


def test_table2_verdict_per_metric_is_none_safe(flat_run):
    from sparsebtf.evaluation.claims3 import summarise_table3

    rows = []
    for m, mse, log in (("sparsebtf", 1.0, 1.0), ("raw", 4.0, 1.5)):
        for mat in ("a", "b"):
            rows.append({"material": mat, "set": "test", "method": m, "level": 32,
                         "mse_rgb": mse, "mse_log": log})  # fmt: skip
    s = summarise_table3({"config": {"levels": [32]}, "rows": rows}, 32)["table2_metrics"]
    assert s["per_metric"]["mse_rgb"]["verdict"] == "supported"
    assert s["per_metric"]["mse_log"]["verdict"] == "partly supported"
    assert s["per_metric"]["mse_display"]["verdict"] == "not measured"  # no such metric
    assert s["verdict"] == "differs by metric"


def test_report_regenerates_docs_from_an_old_results_json(tmp_path):
    """docs/results/results.json predates methods and matchings: bench report still reads it,
    with every existing section, and its verdicts unchanged."""
    from sparsebtf.evaluation.report import summarise

    old = DOCS / "results" / "results.json"
    run = tmp_path / "run"
    run.mkdir()
    shutil.copyfile(old, run / "results.json")
    assert main(["bench", "report", str(run), "--docs", str(tmp_path / "docs")]) == 0
    text = (tmp_path / "docs" / "results.md").read_text()
    for head in ("## Verdicts", "## Table 2 shape", "## Table 3 shape", "## Table 3: SparseBTF",
                 "## Table 5 shape", "## Storage of every method", "## Figure 3 shape"):
        assert head in text, head
    data = json.loads(old.read_text())
    if "summary" in data:
        now = summarise(data)
        for key, entry in data["summary"].items():
            if isinstance(entry, dict) and "verdict" in entry:
                assert now[key]["verdict"] == entry["verdict"], key

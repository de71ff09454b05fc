"""``bench quality`` with adaptive patch sizes (issue 35, ``sparsebtf-adaptive``) on the tiny
configuration: the method codes every test material at the reference's bytes (never above),
its verdict follows its rule both ways, its tree picture is written and reported."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from sparsebtf.codec import train
from sparsebtf.codec.train import join_patch_sizes
from sparsebtf.errors import BTFInputError
from sparsebtf.evaluation.adaptive_verdicts import adaptive_verdict, summarise_adaptive
from sparsebtf.evaluation.methods.adaptive import adaptive_sizes
from sparsebtf.evaluation.methods.selection import parse_methods
from sparsebtf.evaluation.plots import tree_figure
from sparsebtf.evaluation.report import regenerate

from .conftest import smooth_btf
from .test_evaluation import tiny_bench, tiny_config

METHOD = "sparsebtf-adaptive"


@pytest.fixture(scope="module")
def adaptive_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("adaptive")
    cfg = replace(tiny_config(), with_per_channel=False, with_raw=False, pca_domains=(),
                  black_materials=(), render_spp=0, speed_seconds=0.0)  # fmt: skip
    return out / "run", tiny_bench(out, ["sparsebtf", "rate", METHOD], cfg)


def test_methods_option_takes_it_and_an_odd_patch_is_one_line():
    assert parse_methods(f"sparsebtf,{METHOD}") == ["sparsebtf", METHOD]
    assert adaptive_sizes(10) == (10, 5)
    with pytest.raises(BTFInputError, match="patch 5 must be even"):
        adaptive_sizes(5)


def test_coded_at_the_reference_bytes_never_above(adaptive_run):
    out, _ = adaptive_run
    data = json.loads((out / "results.json").read_text())
    ref = {(r["material"], r["level"]): r for r in data["rows"]
           if r["method"] == "sparsebtf" and r["set"] == "test" and r["level"] is not None}
    rows = [r for r in data["rows"] if r["method"] == METHOD]
    assert {(r["material"], r["level"]) for r in rows} == set(ref)
    for r in rows:
        budget = ref[(r["material"], r["level"])]["material_bytes"]
        assert r["budget_bytes"] == budget
        # the tree's bits are in its Table 4 bytes, which stay within the reference's
        assert r["bytes_tree"] >= 1 and r["material_bytes"] <= budget
        assert r["material_bytes"] > 0.9 * budget  # the budget is spent, not left over
        assert r["mse_rgb"] > 0 and r["encode_seconds"] > 0 and r["fixed_encode_seconds"] > 0
        assert set(r["nodes"]) == {"4", "2"} and 0 <= r["small_texel_share"] <= 1
        # the fixed code timed beside it is the reference's own (its error, from the codes)
        assert r["mse_std_fixed"] == pytest.approx(ref[(r["material"], r["level"])]["mse_std"])
        assert r["mse_std_coded"] > 0 and r["mse_std_small"] > 0
    model = data["models"][METHOD]
    assert model["params"]["patch_sizes"] == [4, 2]
    # the 4x4 ensemble is the reference's (same settings and seed): only 2x2 was trained
    assert data["method_runs"][METHOD]["params"]["reuses_reference_ensemble"] is True
    assert model["training"] == data["models"]["sparsebtf"]["training"]
    assert data["method_runs"][METHOD]["shared_bytes"] > data["method_runs"]["sparsebtf"][
        "shared_bytes"]


def test_verdict_picture_and_report(adaptive_run, tmp_path):
    out, _ = adaptive_run
    data = json.loads((out / "results.json").read_text())
    s = data["summary"]["adaptive_patches"]
    # no PCA in this run: no Table 5 verdict (not a "not supported" over nothing)
    assert "table5_pca" not in data["summary"]
    rated = [r["mse_rgb"] / next(x["mse_rgb"] for x in data["rows"] if x["method"] == "rate"
                                 and (x["material"], x["level"]) == (r["material"], r["level"]))
             for r in data["rows"] if r["method"] == METHOD]  # fmt: skip
    assert s["verdict"] == adaptive_verdict(
        [v for m in s["per_material"].values() for v in m["per_level"].values()], True, rated)
    assert s["small_std_ratio_geomean"] > 0
    assert s["rule"] and s["bytes_max_fraction"] <= 1 and s["encode_time_ratio"] > 0
    assert set(s["per_material"]) == {"carpet12", "stone12"}
    assert s["vs_rate_geomean"] > 0
    # every test material's tree at the reference level is drawn; the report shows one
    drawn = [r["tree_figure"] for r in data["rows"] if r["method"] == METHOD and r["level"] == 32]
    assert len(drawn) == 2 and all((out / p).stat().st_size > 1000 for p in drawn)
    assert s["tree_figure"] in drawn
    md = (out / "results.md").read_text()
    assert "## Adaptive patch sizes" in md and f"]({s['tree_figure']})" in md
    assert f"--methods sparsebtf,rate,{METHOD} --out DIR`" in md  # the command it was run by
    assert "adaptive patch sizes (a rate-distortion quadtree of 4x4 and 2x2 nodes)" in md
    text = regenerate(out, tmp_path / "docs").read_text()
    name = s["tree_figure"].rsplit("/", 1)[-1]
    assert f"](results/{name})" in text and (tmp_path / "docs" / "results" / name).exists()


def _result(adaptive: list[float], fixed: list[float], spent: float = 1.0,
            rate: list[float] | None = None) -> dict:  # fmt: skip
    """A results object of two materials at levels 16 and 32 with the given MSEs."""
    rows = []
    for i, (a, f) in enumerate(zip(adaptive, fixed, strict=True)):
        base = {"material": f"m{i // 2}", "level": (16, 32)[i % 2], "set": "test"}
        rows.append({**base, "method": "sparsebtf", "mse_rgb": f, "material_bytes": 1000})
        if rate is not None:
            rows.append({**base, "method": "rate", "mse_rgb": rate[i], "material_bytes": 1000})
        rows.append({**base, "method": METHOD, "mse_rgb": a, "budget_bytes": 1000,
                     "material_bytes": int(1000 * spent), "small_texel_share": 0.25 * i,
                     "nodes": {"10": 3, "5": 4}, "encode_seconds": 3.0,
                     "fixed_encode_seconds": 1.0})  # fmt: skip
    return {"rows": rows, "config": {"levels": [16, 32]}}


@pytest.mark.parametrize(("scale", "verdict"), [
    (0.9, "supported"), (1.1, "not supported (higher error)"), (1.0, "no clear difference"),
])  # fmt: skip
def test_verdict_rule_on_hand_made_rows(scale, verdict):
    fixed = [4.0, 2.0, 3.0, 1.0]
    s = summarise_adaptive(_result([scale * f for f in fixed], fixed), [16, 32],
                           32)["adaptive_patches"]  # fmt: skip
    assert s["verdict"] == verdict
    assert s["ratio_geomean"] == pytest.approx(scale)
    assert s["pairs_lower"] == f"{4 if scale < 1 else 0}/4"
    assert s["per_material"]["m1"]["per_level"]["16"] == pytest.approx(scale)
    assert s["encode_time_ratio"] == pytest.approx(3.0)


def test_verdict_rule_mixed_and_over_budget():
    # lower on one material, higher on the other: the geometric mean decides, per material
    # the breakdown says where it pays
    s = summarise_adaptive(_result([0.5, 1.0, 6.0, 2.0], [1.0, 2.0, 3.0, 1.0]), [16, 32],
                           32)["adaptive_patches"]  # fmt: skip
    assert s["verdict"] == "no clear difference" and s["pairs_lower"] == "2/4"
    assert s["per_material"]["m0"]["ratio_geomean"] == pytest.approx(0.5)
    assert s["per_material"]["m1"]["ratio_geomean"] == pytest.approx(2.0)
    # lower than fixed tau: whether also lower than rate control says where the gain is
    s = summarise_adaptive(_result([0.9] * 4, [1.0] * 4, rate=[0.9] * 4), [16, 32], 32)
    assert s["adaptive_patches"]["verdict"].startswith("supported against fixed tau only: no "
                                                       "lower than rate control")
    s = summarise_adaptive(_result([0.9] * 4, [1.0] * 4, rate=[0.85] * 4), [16, 32], 32)
    assert "only: higher than rate control" in s["adaptive_patches"]["verdict"]
    s = summarise_adaptive(_result([0.8] * 4, [1.0] * 4, rate=[0.9] * 4), [16, 32], 32)
    assert s["adaptive_patches"]["verdict"] == "supported, and lower than rate control too"
    assert s["adaptive_patches"]["pairs_lower_than_rate"] == "4/4"
    over = summarise_adaptive(_result([0.5] * 4, [1.0] * 4, spent=1.01), [16, 32], 32)
    assert over["adaptive_patches"]["verdict"].startswith("not measured")
    assert summarise_adaptive({"rows": [], "config": {"levels": [16]}}, [16], 16) == {}


def test_tree_figure_is_written(tmp_path):
    texture = np.random.default_rng(0).random((8, 8, 3))
    nodes = np.array([[0, 0, 4], [0, 4, 4], [4, 0, 4], [4, 4, 2], [4, 6, 2], [6, 4, 2],
                      [6, 6, 2]])  # fmt: skip
    path = tree_figure(texture, nodes, (4, 2), tmp_path / "tree.png", "a tree")
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_joined_sizes_equal_training_them_together():
    """Reusing the reference's ensemble is what train(patch=(P, P/2)) would have made."""
    btfs = [smooth_btf(s) for s in range(2)]
    kw = {"n_dictionaries": 2, "tau_train": (16, 4, 4), "sample": 1.0, "max_iter": 1,
          "progress": False}
    both = train(btfs, patch=(4, 2), **kw)
    joined = join_patch_sizes([train(btfs, patch=4, **kw), train(btfs, patch=2, **kw)])
    assert joined.content_hash == both.content_hash
    assert joined.patch_sizes == (4, 2) and joined.params == both.params
    with pytest.raises(BTFInputError, match="largest first"):
        join_patch_sizes([train(btfs, patch=2, **kw), train(btfs, patch=4, **kw)])

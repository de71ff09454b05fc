"""``bench quality`` with the training variants beyond the paper (issue 34) on the tiny
configuration: each trains its own ensemble, codes the test materials at the reference's
bytes, and gets a verdict with its rule."""

from __future__ import annotations

import json
from dataclasses import replace

import pytest

from sparsebtf.evaluation.methods.beyond import multitau_levels
from sparsebtf.evaluation.training_verdicts import iterations_to_reach

from .test_evaluation import tiny_config

VARIANTS = ("sparsebtf-multitau", "sparsebtf-learntau", "sparsebtf-precluster")


@pytest.fixture(scope="module")
def variants_run(tmp_path_factory):
    import os

    from sparsebtf.evaluation.runner import run_quality

    out = tmp_path_factory.mktemp("variants")
    os.environ["SPARSEBTF_CACHE"] = str(out / "cache")
    os.environ["SPARSEBTF_PROGRESS"] = "0"
    cfg = replace(tiny_config(), with_per_channel=False, with_raw=False, with_rate_control=False,
                  pca_domains=("log",), black_materials=())  # fmt: skip
    result = run_quality(out / "run", cfg, log=lambda m: None,
                         methods=["sparsebtf", "training"])  # fmt: skip
    return out / "run", result


def test_levels_rule():
    assert multitau_levels((256, 32, 32), 8) == [(256, 32, 32), (885, 64, 64)]
    assert multitau_levels((256, 32, 32), 9) == [(64, 8, 8), (256, 32, 32), (885, 64, 64)]
    assert multitau_levels((256, 32, 32), 7) == [(256, 32, 32)]
    assert iterations_to_reach([3.0, 2.0, 1.0], 2.0) == 1
    assert iterations_to_reach([3.0, 2.5], 2.0) is None


def test_variants_are_coded_at_the_reference_bytes_with_verdicts(variants_run):
    out, _ = variants_run
    data = json.loads((out / "results.json").read_text())
    ref = {(r["material"], r["level"]): r for r in data["rows"]
           if r["method"] == "sparsebtf" and r["set"] == "test" and r["level"] is not None}
    for method in VARIANTS:
        rows = [r for r in data["rows"] if r["method"] == method]
        assert {(r["material"], r["level"]) for r in rows} == set(ref)
        for r in rows:
            assert r["material_bytes"] == ref[(r["material"], r["level"])]["material_bytes"]
            assert r["mse_rgb"] > 0
        assert data["method_runs"][method]["training_budget"]["seconds"] > 0
    models = data["models"]
    assert models["sparsebtf-multitau"]["params"]["tau_dictionaries"]["Y"] == [8, 28]
    assert models["sparsebtf-learntau"]["params"]["tau_learn"] is True
    # validated at the τ_t the run codes its two levels at (Y of level 16, then 32)
    coded = [r["tau"] for r in data["rows"] if r["method"] == "sparsebtf" and r["set"] == "test"
             and r["level"] in (16, 32) and r["material"] == "carpet12"]
    assert models["sparsebtf-learntau"]["params"]["tau_validation"]["Y"] == [t[0] for t in coded]
    assert models["sparsebtf-precluster"]["params"]["init"] == "preclustered"
    s = data["summary"]
    for key in ("training_multitau", "training_learntau", "training_precluster"):
        assert s[key]["verdict"] and s[key]["rule"] and s[key]["ratio_geomean"] > 0
    its = s["training_precluster"]["iterations"]
    assert set(its) == {"Y", "U", "V"} and all(v["reference"] >= 1 for v in its.values())
    md = (out / "results.md").read_text()
    assert "pre-clustered training reaches" in md and "SparseBTF, several tau_l" in md

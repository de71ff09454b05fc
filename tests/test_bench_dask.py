"""``bench quality`` on a local Dask cluster: every method's per-material codings (the neural
trainings) run as tasks, and the rows equal an in-process run's with the same seed."""

from __future__ import annotations

import json
import math
from dataclasses import replace

import pytest

torch = pytest.importorskip("torch")

from sparsebtf.evaluation.neural import neumip, rgjw20, rjgw19  # noqa: E402
from sparsebtf.evaluation.runner import run_quality  # noqa: E402

from .test_evaluation import tiny_config  # noqa: E402
from .test_neural import TINY  # noqa: E402


# module level: the cluster's workers unpickle them by reference
class TinyRJGW19(rjgw19.RJGW19Method):
    @classmethod
    def from_config(cls, config):
        return cls(**TINY["rjgw19"], device=cls.config_device(config))


class TinyNeuMIP(neumip.NeuMIPMethod):
    @classmethod
    def from_config(cls, config):
        return cls(**TINY["neumip"], device=cls.config_device(config))


class TinyRGJW20FT(rgjw20.RGJW20FineTunedMethod):
    @classmethod
    def from_config(cls, config):
        return cls(**TINY["rgjw20+ft"], device=cls.config_device(config))


METHODS = ["sparsebtf", TinyRJGW19, TinyNeuMIP, TinyRGJW20FT]


def _timeless(x):
    """``x`` without wall or CPU seconds (the only fields that may differ between runs)."""
    if isinstance(x, dict):
        return {k: _timeless(v) for k, v in x.items() if "seconds" not in k}
    if isinstance(x, list):
        return [_timeless(v) for v in x]
    if isinstance(x, float) and math.isnan(x):
        return "nan"
    return x


def _run(out, monkeypatch, device=None, **where):
    monkeypatch.setenv("SPARSEBTF_CACHE", str(out.parent / "cache"))
    monkeypatch.setenv("SPARSEBTF_PROGRESS", "0")
    cfg = replace(tiny_config(), black_materials=(), render_spp=0, speed_seconds=0,
                  test_size=16, table5_materials=(), with_raw=False, with_rate_control=False,
                  with_per_channel=False, pca_domains=(), torch_device=device)  # fmt: skip
    run_quality(out, cfg, log=lambda m: None, methods=METHODS, **where)
    return json.loads((out / "results.json").read_text())


def test_rows_on_two_workers_equal_a_run_in_process(tmp_path, monkeypatch):
    here = _run(tmp_path / "here", monkeypatch)
    # the device (bench quality --device) travels to the workers with the methods; an explicit
    # "cpu" gives the default's rows
    there = _run(tmp_path / "there", monkeypatch, device="cpu", workers=2)
    neural = {r["method"] for r in here["rows"]} - {"sparsebtf"}
    assert neural == {"rjgw19", "neumip", "rgjw20+ft"}
    trained = [r for r in here["rows"] if r["method"] in neural and r["mse_rgb"] is not None]
    assert {r["method"] for r in trained} == neural and all(r["loss_curve"] for r in trained)
    assert _timeless(there["rows"]) == _timeless(here["rows"])
    assert all(r["device"] == "cpu" for r in there["rows"] if r["method"] in neural
               and r["mse_rgb"] is not None)  # fmt: skip
    assert there["config"]["torch_device"] == "cpu" and here["config"]["torch_device"] is None
    assert {there["method_runs"][n]["params"]["device"] for n in neural} == {"cpu"}
    # the trainings that ran on the workers are counted by the run's methods
    for name in neural:
        a = here["method_runs"][name]["training_budget"]
        b = there["method_runs"][name]["training_budget"]
        assert a["trainings"] == b["trainings"] > 0 and a["converged"] == b["converged"]
        assert b["cpu_seconds"] > 0

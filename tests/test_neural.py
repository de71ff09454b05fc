"""The neural baselines (RGJW20, RGJW20 + fine-tuning, RJGW19, NeuMIP without offset) on tiny
materials: 4x4 texels, 13 directions, a few training steps."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from sparsebtf.evaluation.methods import (  # noqa: E402
    PAPER,
    PER_MATERIAL,
    Budget,
    FitContext,
    method_class,
)
from sparsebtf.evaluation.neural import neumip, rgjw20, rjgw19  # noqa: E402
from sparsebtf.evaluation.neural._torch import NeuralBTF, mlp_params  # noqa: E402

from .conftest import smooth_btf  # noqa: E402

TINY_RGJW20 = dict(max_queries_per_texel=48, eval_every=16, texels_per_step=8,
                   encoder_samples=16, loss_samples=16, train_texels=16, pool=48,
                   code_samples=32, heldout=4)  # fmt: skip
TINY = {
    "rgjw20": TINY_RGJW20,
    "rgjw20+ft": {**TINY_RGJW20, "finetune_max_queries_per_texel": 32, "finetune_queries": 8},
    "rjgw19": dict(max_queries_per_texel=40, eval_every=16, texels_per_step=8,
                   queries_per_step=16, pool=48, heldout=4),
    "neumip": dict(max_queries_per_texel=32, eval_every=16, blur_queries_per_texel=16,
                   queries_per_step=8, pool=48, heldout=4),
}
NAMES = tuple(TINY)
#: per-texel bytes of SparseBTF at the tests' two levels (any values: they pick the sizes)
LEVEL_BYTES = {2: 3.0, 4: 9.0}
CONTEXT = FitContext(levels=(2, 4), level_bytes_per_texel=LEVEL_BYTES)
HW = 16  # 4x4 texels


def budgets(name: str) -> list[Budget]:
    """Budgets large enough for a per-material decoder at 4x4 texels."""
    if name.startswith("rgjw20"):
        return [Budget(2, 2 * 2 * HW, PAPER), Budget(4, int(LEVEL_BYTES[4] * HW), PER_MATERIAL)]
    return [Budget(2, 12_000, PAPER), Budget(4, 16_000, PER_MATERIAL)]


def fitted(name: str, seed: int = 0, **kw):
    cls = method_class(name)
    method = cls(**{**TINY[name], "seed": seed, **kw})
    train = [smooth_btf(s, size=4, name=f"train{s}") for s in range(2)]
    return method.fit(train, CONTEXT)


@pytest.fixture(scope="module")
def test_btf():
    return smooth_btf(7, size=4, name="test7")


@pytest.fixture(scope="module")
def codings(test_btf):
    return {name: fitted(name).code(test_btf, budgets(name)) for name in NAMES}


def test_registry_resolves_every_neural_method():
    expected = {"rgjw20": rgjw20.RGJW20Method, "rgjw20+ft": rgjw20.RGJW20FineTunedMethod,
                "rjgw19": rjgw19.RJGW19Method, "neumip": neumip.NeuMIPMethod}  # fmt: skip
    for name, cls in expected.items():
        assert method_class(name) is cls
        assert cls.name == name
    assert rgjw20.RGJW20FineTunedMethod.label != rgjw20.RGJW20Method.label


def test_importing_sparsebtf_does_not_import_torch():
    code = ("import sys, sparsebtf, sparsebtf.evaluation.methods, sparsebtf.evaluation.neural; "
            "print('torch' in sys.modules)")  # fmt: skip
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


@pytest.mark.parametrize("name", NAMES)
def test_codes_and_decodes_with_bytes_of_its_stored_arrays(name, codings, test_btf):
    out = codings[name]
    assert len(out) == 2
    shared = name.startswith("rgjw20")
    for coding, budget in zip(out, budgets(name), strict=True):
        rec = coding.reconstruction
        assert isinstance(rec, NeuralBTF) and rec.shape == test_btf.shape
        values = rec.read(slice(None), slice(None), slice(None), slice(None))
        assert values.dtype == np.float32 and np.all(np.isfinite(values)) and values.min() >= 0
        stored = rec.stored()
        assert all(a.dtype == np.float16 for a in stored.values())
        code_bytes = 2 * stored["code"].size
        decoder_bytes = 2 * sum(a.size for k, a in stored.items() if k != "code")
        if shared:
            assert coding.material_bytes == code_bytes
            assert coding.shared_bytes == decoder_bytes
        else:
            assert coding.material_bytes == code_bytes + decoder_bytes
            assert coding.shared_bytes == 0
        assert coding.material_bytes <= budget.material_bytes
        assert coding.info["matching"] == budget.matching
        size = coding.info.get("latent_size", coding.info.get("channels"))
        assert stored["code"].shape == (4, 4, size)
        assert coding.info["decoder_params"] == decoder_bytes // 2


def test_sizes_follow_the_budgets(codings):
    # paper matching: L = level; per material: floor(bytes per texel / 2), decoder shared
    assert [c.info["latent_size"] for c in codings["rgjw20"]] == [2, 4]
    # per-material decoders: the largest size whose code and decoder fit
    for name, key, sizes in (("rjgw19", "latent_size", rjgw19.RECIPE.decoder_sizes),
                             ("neumip", "channels", neumip.RECIPE.mlp_sizes)):  # fmt: skip
        for coding, budget in zip(codings[name], budgets(name), strict=True):
            n = coding.info[key]
            assert 2 * HW * n + 2 * mlp_params(sizes(n)) <= budget.material_bytes
            assert 2 * HW * (n + 1) + 2 * mlp_params(sizes(n + 1)) > budget.material_bytes


def test_rgjw20_trains_one_model_per_needed_latent_size():
    context = FitContext(levels=(16, 32), level_bytes_per_texel={16: 18.7, 32: 50.8})
    assert rgjw20.RGJW20Method().sizes_for(context) == [9, 16, 25, 32]
    method = fitted("rgjw20")
    assert sorted(method.models_) == [1, 2, 4]  # levels 2, 4; floor(3/2), floor(9/2)
    budget = method.training_budget()
    assert budget["trainings"] == 3 and budget["seconds"] >= 0 and budget["cpu_seconds"] > 0
    assert 0 < budget["queries_per_texel"] <= TINY_RGJW20["max_queries_per_texel"] + 1


def test_fine_tuning_keeps_the_networks_and_changes_the_latents(codings):
    plain, tuned = codings["rgjw20"][0], codings["rgjw20+ft"][0]
    for (name, a) in plain.reconstruction.stored().items():
        b = tuned.reconstruction.stored()[name]
        if name == "code":
            assert not np.array_equal(a, b)
        else:
            np.testing.assert_array_equal(a, b)
    assert "finetune" in tuned.info and "finetune" not in plain.info


@pytest.mark.parametrize("name", NAMES)
def test_same_seed_same_latents(name, test_btf):
    def code(seed: int) -> np.ndarray:
        rgjw20._TRAINED.clear()  # train again: the memo would make equal seeds trivially equal
        rec = fitted(name, seed).code(test_btf, budgets(name)[:1])[0].reconstruction
        return rec.stored()["code"]

    a, b, c = code(3), code(3), code(4)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)


def _manual_decode(rec: NeuralBTF, r, c, li, vi) -> np.ndarray:
    """The network evaluated directly on the binary16 arrays cast to float32."""
    s = {k: v.astype(np.float32) for k, v in rec.stored().items()}
    x = np.concatenate([s["code"][r, c], rec.lights.xyz[li, :2], rec.views.xyz[vi, :2]], axis=1)
    n_layers = sum(k.endswith(".weight") for k in s)
    for i in range(n_layers):
        x = x @ s[f"layer{i}.weight"].T + s[f"layer{i}.bias"]
        if i < n_layers - 1:
            x = np.where(x > 0, x, rec.slope * x)
    if rec.head == "log1p":
        out = np.expm1(x)
    else:
        y, u, v = x[:, 0], x[:, 1], x[:, 2]
        log_rgb = np.stack([y + 1.13983 * v, y - 0.39465 * u - 0.58060 * v, y + 2.03211 * u], 1)
        out = np.expm1(log_rgb) * (0.1 + 1 / (1 + np.exp(-x[:, 3:6])))
    return np.maximum(out, 0)


@pytest.mark.parametrize("name", NAMES)
def test_reconstruction_is_the_binary16_network_and_query_equals_read(name, codings):
    rec = codings[name][0].reconstruction
    rng = np.random.default_rng(0)
    r, c, li, vi = (rng.integers(0, n, 40) for n in (4, 4, 13, 13))
    queried = rec.query(r, c, li, vi)
    assert queried.shape == (40, 3)
    read = np.stack([rec.read([a], [b], [x], [y])[0, 0, 0, 0] for a, b, x, y in
                     zip(r, c, li, vi, strict=True)])  # fmt: skip
    np.testing.assert_allclose(queried, read, rtol=1e-5, atol=1e-7)
    np.testing.assert_allclose(queried, _manual_decode(rec, r, c, li, vi), rtol=1e-4, atol=1e-6)
    # the latents / texture really are binary16 values: float32 ones would differ
    assert rec.stored()["code"].dtype == np.float16
    # a renderer's continuous directions: at the measured ones, the same values
    looked = rec.lookup(r, c, rec.lights.xyz[li], rec.views.xyz[vi])
    np.testing.assert_allclose(looked, queried, rtol=1e-5, atol=1e-7)
    mid = rec.lights.xyz[li] + rec.lights.xyz[(li + 1) % 13]
    mid /= np.linalg.norm(mid, axis=1, keepdims=True)
    assert not np.allclose(rec.lookup(r, c, mid, rec.views.xyz[vi]), looked)


@pytest.mark.parametrize("name", ["rjgw19", "neumip", "rgjw20"])
def test_budget_too_small_gives_no_reconstruction_and_a_note(name, test_btf):
    method = fitted(name)
    coding = method.code(test_btf, [Budget(1, 8, PAPER)])[0]
    assert coding.reconstruction is None and coding.material_bytes == 0
    assert coding.note and "B" in coding.note


def test_rgjw20_codes_only_after_fit(test_btf):
    from sparsebtf.errors import BTFInputError

    with pytest.raises(BTFInputError, match="fit"):
        rgjw20.RGJW20Method(**TINY_RGJW20).code(test_btf, budgets("rgjw20"))


def test_query_rejects_unequal_lengths(codings):
    from sparsebtf.errors import BTFInputError

    rec = codings["neumip"][0].reconstruction
    with pytest.raises(BTFInputError, match="differ in length"):
        rec.query([0, 1], [0], [0], [0])


def test_from_config_picks_the_effort():
    from sparsebtf.evaluation.benchmark_set import BenchConfig

    quick, full = BenchConfig.quick(), BenchConfig()
    for name in NAMES:
        cls = method_class(name)
        q, f = cls.from_config(quick), cls.from_config(full)
        assert type(q) is cls and type(f) is cls
        assert q.describe() != f.describe()


@pytest.mark.parametrize("name", NAMES)
def test_a_pickled_fitted_method_codes_the_same(name, test_btf):
    """What ``bench quality --resume`` relies on: a fitted method's pickle (its checkpoint)
    codes exactly as the method did."""
    import pickle

    method = fitted(name, 5)
    copy = pickle.loads(pickle.dumps(method))
    a = method.code(test_btf, budgets(name)[:1])[0]
    b = copy.code(test_btf, budgets(name)[:1])[0]
    np.testing.assert_array_equal(a.reconstruction.stored()["code"],
                                  b.reconstruction.stored()["code"])  # fmt: skip
    assert a.material_bytes == b.material_bytes

"""Figure 8 for every method (evaluation.renders): dense-plugin renders, their MSE and ꟻLIP.

Skips (with the reason) when Mitsuba or flip_evaluator is missing or Dr.Jit's LLVM backend is
unusable, as tests/test_mitsuba.py does.
"""

from __future__ import annotations

import importlib.util

import numpy as np
import pytest

from sparsebtf import llvm
from sparsebtf.data.btf import ArrayBTF
from sparsebtf.errors import BTFInputError

from .conftest import smooth_btf

if importlib.util.find_spec("mitsuba") is None or importlib.util.find_spec("drjit") is None:
    pytest.skip("mitsuba/drjit not installed (pip install mitsuba drjit)", allow_module_level=True)
if importlib.util.find_spec("flip_evaluator") is None:
    pytest.skip("flip_evaluator not installed (pip install flip-evaluator)",
                allow_module_level=True)  # fmt: skip
_status = llvm.configure()
if not _status.ok:
    pytest.skip(f"Dr.Jit LLVM backend unusable here: {_status.message()}", allow_module_level=True)

import sparsebtf.mitsuba as sbm  # noqa: E402
from sparsebtf.evaluation.renders import dense_copy, flip_hdr, render_methods  # noqa: E402
from sparsebtf.rendering.mitsuba import materials  # noqa: E402


@pytest.fixture(autouse=True)
def _llvm_variant():
    sbm.setup("llvm")
    yield


def test_render_methods_identical_and_perturbed(tmp_path):
    ref = smooth_btf(9)
    rng = np.random.default_rng(2)
    noisy = ArrayBTF(ref.data * rng.uniform(0.7, 1.3, ref.data.shape).astype(np.float32),
                     ref.lights, ref.views, name="noisy")  # fmt: skip
    dark = ArrayBTF(ref.data * np.float32(0.5), ref.lights, ref.views, name="dark")
    got = render_methods(ref, {"same": ref, "noisy 30%": noisy, "half/bright": dark},
                         tmp_path / "fig", spp=4, image_size=24, seed=3)  # fmt: skip
    assert set(got) == {"same", "noisy 30%", "half/bright"}
    same = got["same"]
    assert same["image_mse"] == 0 and same["image_mse_display"] == 0 and same["flip"] == 0
    for label in ("noisy 30%", "half/bright"):
        r = got[label]
        assert r["image_mse"] > 0 and r["image_mse_display"] > 0 and 0 < r["flip"] < 1, label
    # halving the material is a larger error than 30 % noise around it, in every metric
    for key in ("image_mse", "image_mse_display", "flip"):
        assert got["half/bright"][key] > got["noisy 30%"][key], key
    out = tmp_path / "fig"
    assert (out / "figure8.png").stat().st_size > 0 and (out / "reference.png").exists()
    assert got["half/bright"]["png"].endswith("half_bright.png")
    for r in got.values():
        assert (out / r["png"]).exists()
    raw = np.load(out / "renders.npz")
    assert raw["reference"].shape == (24, 24, 3) and np.array_equal(raw["same"], raw["reference"])
    # the metrics are the renders'
    d = raw["half_bright"].astype(np.float64) - raw["reference"]
    assert got["half/bright"]["image_mse"] == pytest.approx(np.mean(d**2), rel=1e-6)
    assert got["half/bright"]["flip"] == pytest.approx(
        flip_hdr(raw["reference"], raw["half_bright"])[1], rel=1e-6)
    # nothing left in the plugins' registry
    assert not any("sparsebtf-evaluation-renders" in str(k) for k in materials._materials)


def test_dense_copy_of_a_coded_btf_is_its_decode():
    """View block by view block (Eq. 4 per view) gives the whole-BTF decode."""
    from sparsebtf.codec import encode
    from sparsebtf.runtime import coded_btf_view

    from .conftest import tiny_model

    view = coded_btf_view(encode(smooth_btf(9), tiny_model(1), tau=(20, 4, 4), eps=0.0,
                                 progress=False))  # fmt: skip
    copy = dense_copy(view, "coded")
    np.testing.assert_allclose(copy.data, view.to_array(), rtol=1e-6, atol=1e-7)
    assert copy.lights.equals(view.lights) and copy.views.equals(view.views)


def test_render_methods_refuses_bad_input(tmp_path):
    ref = smooth_btf(9)
    with pytest.raises(BTFInputError, match="shape"):
        render_methods(ref, {"small": smooth_btf(1, size=4)}, tmp_path)
    big = ArrayBTF(np.zeros((101, 8, 13, 13, 3), np.float32), ref.lights, ref.views, name="big")
    with pytest.raises(BTFInputError, match=r"up to 100x100 texels.*101x8"):
        render_methods(big, {}, tmp_path)
    bad = ref.data.copy()
    bad[1, 2, 3, 4, 0] = np.nan
    with pytest.raises(BTFInputError, match=r"1 non-finite values \(first at .* \(1, 2, 3, 4\)"):
        dense_copy(ArrayBTF(bad, ref.lights, ref.views), "nan method")
    assert not (tmp_path / "figure8.png").exists()

"""Inter-BTF interpolation (§3.5, Eq. 7–9) and ``sparsebtf blend``."""

import json
from dataclasses import replace

import numpy as np
import pytest

from sparsebtf.cli.main import main
from sparsebtf.codec import encode, train
from sparsebtf.data.directions import tiny
from sparsebtf.errors import BTFInputError, ModelMismatchError
from sparsebtf.learning.coding import SparseCodes
from sparsebtf.model import CodedBTF
from sparsebtf.runtime import blend, decode_points
from sparsebtf.storage import load_coded, save_coded, save_model

from .conftest import smooth_btf, tiny_model

FULL = 4 * 4 * 13 * 13  # every coefficient of a data point


@pytest.fixture(scope="module")
def pair():
    model = tiny_model()
    a = encode(smooth_btf(7, name="a"), model, tau=(40, 8, 8), eps=0.0, progress=False)
    b = encode(smooth_btf(8, name="b"), model, tau=(40, 8, 8), eps=0.0, progress=False)
    # Make b's points use other dictionaries than a's, so Eq. 8–9 is exercised for sure.
    codes = {}
    for ch, c in b.codes.items():
        memb = (a.codes[ch].membership.astype(np.int64) + 1) % 3
        codes[ch] = replace(c, membership=memb.astype(c.membership.dtype))
    b = replace(b, codes=codes)
    return model, a, b


def _decoded(coded, ch):
    return decode_points(coded, ch, np.arange(coded.n_points))


def _same_codes(x: SparseCodes, y: SparseCodes):
    assert np.array_equal(x.membership, y.membership)
    assert np.array_equal(x.counts, y.counts)
    for i in range(x.n_points):
        lx, vx = x.point(i)
        ly, vy = y.point(i)
        ox = np.lexsort(lx.T[::-1])
        oy = np.lexsort(ly.T[::-1])
        assert np.array_equal(lx[ox], ly[oy])
        np.testing.assert_array_equal(vx[ox].astype(np.float64), vy[oy].astype(np.float64))


def test_alpha_0_and_1_return_the_inputs(pair):
    _, a, b = pair
    for alpha, src in ((0.0, a), (1.0, b)):
        out = blend([a, b], alpha=alpha, progress=False)
        for ch in a.channels:
            _same_codes(out.codes[ch], src.codes[ch])
        np.testing.assert_array_equal(out.stats.mean, src.stats.mean)
        np.testing.assert_array_equal(out.stats.std, src.stats.std)


def test_cross_dictionary_blend_equals_data_space_blend(pair):
    _, a, b = pair
    alpha = 0.3
    out = blend([a, b], alpha=alpha, tau=FULL, progress=False)  # no re-sparsification
    for ch in a.channels:
        assert np.array_equal(out.codes[ch].membership, a.codes[ch].membership)
        assert (out.codes[ch].membership != b.codes[ch].membership).all()
        want = (1 - alpha) * _decoded(a, ch) + alpha * _decoded(b, ch)
        # coefficients are kept in float32 (files store binary16): rounding ~1e-7
        np.testing.assert_allclose(_decoded(out, ch), want, atol=1e-6)
        assert np.all(out.codes[ch].errors < 1e-14)  # nothing dropped but rounding
    np.testing.assert_allclose(out.stats.mean, 0.7 * a.stats.mean + 0.3 * b.stats.mean)


def test_resparsified_blend_keeps_tau_and_reports_its_error(pair):
    _, a, b = pair
    out = blend([a, b], alpha=0.6, tau=(20, 5, 5), progress=False)
    full = blend([a, b], alpha=0.6, tau=FULL, progress=False)
    for ch, t in zip(a.channels, (20, 5, 5), strict=True):
        c = out.codes[ch]
        assert c.counts.max() == t
        # b dominates (α > ½): its dictionaries are the target
        assert np.array_equal(c.membership, b.codes[ch].membership)
        resid = _decoded(full, ch) - _decoded(out, ch)
        per_point = (resid.reshape(resid.shape[0], -1) ** 2).mean(axis=1)
        np.testing.assert_allclose(c.errors, per_point, rtol=1e-6, atol=1e-15)
        # the kept coefficients are the t largest of the full blend
        for i in range(c.n_points):
            _, v_full = full.codes[ch].point(i)
            _, v = c.point(i)
            np.testing.assert_allclose(np.sort(np.abs(v)), np.sort(np.abs(v_full))[-t:], rtol=1e-6)


def test_same_dictionary_blend_is_a_sparse_sum(pair):
    _, a, _ = pair
    a2 = encode(smooth_btf(11, name="a2"), a.model, tau=(40, 8, 8), eps=0.0, progress=False)
    codes = {ch: replace(c, membership=a.codes[ch].membership.copy()) for ch, c in a2.codes.items()}
    a2 = replace(a2, codes=codes)
    out = blend([a, a2], weights=[0.5, 0.5], tau=FULL, progress=False)
    for ch in a.channels:
        want = 0.5 * _decoded(a, ch) + 0.5 * _decoded(a2, ch)
        np.testing.assert_allclose(_decoded(out, ch), want, atol=1e-6)
        assert out.codes[ch].counts.max() <= 80  # the union of two 40-coefficient supports


def test_blend_refuses_incompatible_inputs(pair):
    model, a, b = pair
    other = train(
        [smooth_btf(s) for s in range(3, 5)], n_dictionaries=2, tau_train=(16, 4, 4), patch=4,
        sample=1.0, max_iter=1, progress=False,
    )  # fmt: skip
    c = encode(smooth_btf(9), other, tau=(40, 8, 8), eps=0.0, progress=False)
    with pytest.raises(ModelMismatchError, match="same model"):
        blend([a, c], alpha=0.5)
    d7 = tiny(7)
    moved = CodedBTF(b.codes, b.stats, b.height, b.width, b.patch, d7, d7, b.model_hash,
                     b.params, "moved", {}, model)  # fmt: skip
    with pytest.raises(BTFInputError, match="different direction tables"):
        blend([a, moved], alpha=0.5)
    with pytest.raises(BTFInputError, match="sum to 1"):
        blend([a, b], weights=[0.5, 0.6])
    with pytest.raises(BTFInputError, match="at least two"):
        blend([a], weights=[1.0])


def test_cli_blend_alpha_and_sweep(pair, tmp_path, capsys):
    model, a, b = pair
    mpath = save_model(model, tmp_path / "model.h5")
    for c in (a, b):
        c.params["model_file"] = str(mpath)
        save_coded(c, tmp_path / f"{c.name}.h5")
    out = tmp_path / "c.h5"
    rc = main([
        "blend", str(tmp_path / "a.h5"), str(tmp_path / "b.h5"), "--alpha", "0.3", "-o", str(out),
        "--sweep", "5", "--png", str(tmp_path / "strip"), "--json",
    ])  # fmt: skip
    assert rc == 0
    report = json.loads(capsys.readouterr().out)
    assert report["weights"] == [0.7, 0.3] and len(report["sweep"]) == 5
    c = load_coded(out, model)
    assert c.params["blend"]["weights"] == [0.7, 0.3]
    strip = tmp_path / "strip" / "blend_strip.png"
    assert strip.stat().st_size > 0
    assert len(list((tmp_path / "strip").glob("blend_alpha_*.png"))) == 5
    # alpha outside [0, 1] is refused with a clear message, nothing written
    assert main(["blend", str(tmp_path / "a.h5"), str(tmp_path / "b.h5"), "--alpha", "2",
                 "-o", str(tmp_path / "bad.h5")]) == 2  # fmt: skip
    assert "alpha" in capsys.readouterr().err
    assert not (tmp_path / "bad.h5").exists()

import numpy as np
import pytest

import sparsebtf.runtime.dense as dense
from sparsebtf.codec import (
    encode,
    encode_levels,
    parse_tau,
    train,
)
from sparsebtf.data.btf import ArrayBTF
from sparsebtf.data.directions import tiny
from sparsebtf.errors import BTFInputError, ModelMismatchError
from sparsebtf.metrics import compare
from sparsebtf.runtime import coded_btf_view, decode_points, decode_points_eq5

from .conftest import smooth_btf, tiny_model


@pytest.fixture(scope="module")
def model():
    return tiny_model(max_iter=3)


def test_training_records_monotone_objective(model):
    assert model.channels == ("Y", "U", "V")
    assert model.mode_sizes == (4, 4, 13, 13)
    for ch in model.channels:
        obj = np.array(model.training[ch]["objective"])
        assert np.all(np.diff(obj) <= 1e-9 * obj[0])
        assert sum(model.training[ch]["membership_counts"]) == 12
        for d in model.dictionaries[ch]:
            for k in range(3):
                assert np.allclose(d[k] @ d[k].T, np.eye(d.shape[1]), atol=1e-9)


def test_encode_decode_quality_improves_with_tau(model):
    btf = smooth_btf(9)
    low, high = encode_levels(btf, model, [(16, 4, 4), (200, 40, 40)], eps=0.0, progress=False)
    assert low.nnz() == {"Y": 4 * 16, "U": 4 * 4, "V": 4 * 4}
    m_low = compare(btf, coded_btf_view(low), stats=low.stats, ssim_images=4)
    m_high = compare(btf, coded_btf_view(high), stats=high.stats, ssim_images=4)
    assert m_high["mse_rgb"] < m_low["mse_rgb"]
    assert m_high["psnr_rgb"] > m_low["psnr_rgb"]
    # mse in the standardised domain equals the Parseval errors of the codes
    parseval = np.mean([high.codes[ch].errors.mean() for ch in high.channels])
    assert m_high["mse_std"] == pytest.approx(parseval, rel=1e-3)


def test_eq4_equals_eq5_and_direct_sum(model):
    coded = encode(smooth_btf(8), model, tau=(40, 8, 8), eps=0.0, progress=False)
    pts, li, vi = [0, 3], [1, 7], [0, 5, 12]
    for ch in coded.channels:
        eq5 = decode_points_eq5(coded, ch, pts, li, vi)
        old = dense.EQ5_MAX_DIRECTIONS
        dense.EQ5_MAX_DIRECTIONS = 0
        try:
            eq4 = decode_points(coded, ch, pts, li, vi)
        finally:
            dense.EQ5_MAX_DIRECTIONS = old
        assert np.allclose(eq4, eq5, atol=1e-12)
        # the literal sum of Eq. 5 for one element
        loc, val = coded.codes[ch].point(3)
        k = coded.codes[ch].membership[3]
        u = [d[k] for d in model.dictionaries[ch]]
        direct = sum(
            v * u[0][2, a] * u[1][1, b] * u[2][7, c] * u[3][12, d]
            for v, (a, b, c, d) in zip(val, loc, strict=True)
        )
        assert eq4[1, 2, 1, 1, 2] == pytest.approx(direct, abs=1e-12)


def test_decoded_btf_reads_consistently(model):
    coded = encode(smooth_btf(7), model, tau=(30, 6, 6), progress=False)
    view = coded_btf_view(coded)
    full = view.to_array()
    assert full.shape == (8, 8, 13, 13, 3) and np.isfinite(full).all()
    assert np.allclose(view.angular_image(4, 2), full[:, :, 4, 2], atol=1e-5)
    sub = view.read([1, 6, 7], [0, 5], [3], [2, 9])
    assert np.allclose(sub, full[np.ix_([1, 6, 7], [0, 5], [3], [2, 9], [0, 1, 2])], atol=1e-5)


def test_colour_mode_5d(tmp_path):
    btfs = [smooth_btf(s) for s in range(2)]
    m5 = train(
        btfs,
        n_dictionaries=2,
        tau_train=24,
        patch=4,
        sample=1.0,
        max_iter=2,
        colour_mode=True,
        progress=False,
    )
    assert m5.channels == ("YUV",) and m5.mode_sizes == (4, 4, 13, 13, 3)
    coded = encode(smooth_btf(5), m5, tau=300, eps=0.0, progress=False)
    rec = coded_btf_view(coded).to_array()
    ref = smooth_btf(5).to_array()
    assert np.mean((rec - ref) ** 2) < np.mean(ref**2) * 0.05


def test_encode_bad_input(model):
    with pytest.raises(BTFInputError, match="below the training sparsity"):
        encode(smooth_btf(1), model, tau=(8, 4, 4), progress=False)
    enc = encode(smooth_btf(1), model, tau=(8, 4, 4), allow_below_training=True, progress=False)
    assert enc.nnz()["Y"] == 32
    other = tiny(7)
    btf = ArrayBTF(np.ones((8, 8, 7, 7, 3), np.float32), other, other)
    with pytest.raises(ModelMismatchError, match="direction tables"):
        encode(btf, model, progress=False)
    with pytest.raises(BTFInputError, match="not a multiple of the patch size 4"):
        encode(smooth_btf(1, size=10), model, progress=False)
    with pytest.raises(BTFInputError, match="one value per channel"):
        parse_tau("1,2")
    with pytest.raises(BTFInputError, match="integers"):
        parse_tau("a,b,c")
    with pytest.raises(BTFInputError, match="direction tables"):
        train([smooth_btf(0), smooth_btf(1, n_dirs=7)], progress=False)


def test_staged_training_equals_streamed_training(tmp_path):
    btfs = [smooth_btf(s) for s in range(2)]
    kw = dict(
        n_dictionaries=2, tau_train=(16, 4, 4), patch=4, sample=1.0, max_iter=2, progress=False
    )
    a = train(btfs, stage=True, stage_dir=str(tmp_path), **kw)
    b = train(btfs, stage=False, **kw)
    assert a.content_hash == b.content_hash
    assert list(tmp_path.iterdir()) == []  # the staging file is removed


def test_channel_by_channel_staging(tmp_path, monkeypatch):
    """When all channels do not fit the staging limit but one does, each is staged in turn."""
    import tempfile

    import sparsebtf.points.sources as sources

    btfs = [smooth_btf(s) for s in range(2)]
    kw = dict(
        n_dictionaries=2, tau_train=(16, 4, 4), patch=4, sample=1.0, max_iter=2, progress=False
    )
    need = sources.training_points(btfs, 4, 1.0, 0, progress=False).n_bytes
    monkeypatch.setattr(sources, "STAGE_LIMIT_BYTES", need // 2)
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    staged = []
    init = sources.StagedPoints.__init__

    def spy(self, path, source, channels, *a, **k):
        staged.append(list(channels))
        init(self, path, source, channels, *a, **k)

    monkeypatch.setattr(sources.StagedPoints, "__init__", spy)
    a = train(btfs, **kw)
    assert staged == [["Y"], ["U"], ["V"]]
    assert a.content_hash == train(btfs, stage=False, **kw).content_hash
    assert list(tmp_path.iterdir()) == []

"""The residual analysis of issue 46 (:mod:`sparsebtf.evaluation.residual`) against NumPy: the
highlight split of the squared error, the layouts, low-rank factorisations against a direct
SVD, and the sparse correction against a sort."""

from __future__ import annotations

import numpy as np
import pytest

from sparsebtf.errors import BTFInputError
from sparsebtf.evaluation.residual import (
    allocate_channel_ranks,
    channels_correction,
    error_split,
    gram_spectrum,
    low_rank,
    low_rank_bytes,
    low_rank_channels,
    low_rank_curve,
    residual_matrix,
    sparse_values_curve,
    unflatten_residual,
)

from .conftest import smooth_btf


def _pair(seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """A tiny reference with highlights (4×4 texels, 13 directions) and a noisy decode."""
    ref = smooth_btf(seed, size=4).to_array().astype(np.float64)
    ref[..., 2, 3, :] *= 20  # one (light, view) pair well above 1
    rng = np.random.default_rng(seed)
    dec = np.maximum(ref + 0.05 * rng.standard_normal(ref.shape) * (1 + ref), 0)
    return dec.astype(np.float32), ref.astype(np.float32)


def test_error_split_sums_to_the_mse():
    dec, ref = _pair()
    e = error_split(dec, ref)
    sq = (dec.astype(np.float64) - ref) ** 2
    hi = ref > 1
    assert e["mse"] == pytest.approx(sq.mean())
    assert e["share_above"] == pytest.approx(sq[hi].sum() / sq.sum())
    assert e["mse_above"] == pytest.approx(sq[hi].mean())
    assert e["mse_below"] == pytest.approx(sq[~hi].mean())
    assert e["values_above"] == pytest.approx(hi.mean())
    assert 0 < e["values_above"] < 1 and e["share_above"] > e["values_above"]
    with pytest.raises(BTFInputError):
        error_split(dec[:1], ref)


@pytest.mark.parametrize("layout", ["texels", "directions"])
def test_layouts_round_trip(layout):
    dec, ref = _pair(1)
    res = dec - ref
    m = residual_matrix(res, layout)
    h, w, nl, nv, c = res.shape
    assert m.shape == ((h * w, nl * nv * c) if layout == "texels" else (nl * nv, h * w * c))
    np.testing.assert_array_equal(unflatten_residual(m, res.shape, layout), res)
    if layout == "directions":  # a row is one (light, view) image over texels and channels
        np.testing.assert_array_equal(m[2 * nv + 3], res[:, :, 2, 3, :].ravel())


@pytest.mark.parametrize("layout", ["texels", "directions"])
def test_low_rank_matches_numpy_svd(layout):
    dec, ref = _pair(2)
    m = residual_matrix(dec - ref, layout)
    s_np = np.linalg.svd(m.astype(np.float64), compute_uv=False)
    # a sketch as wide as the smaller side: the direct SVD
    fit, rows = low_rank_curve(m, [1, 2, 4], oversample=min(m.shape))
    np.testing.assert_allclose(fit.s, s_np[:4], rtol=1e-5)
    np.testing.assert_allclose(gram_spectrum(m, chunk=50)[: len(s_np)], s_np**2, rtol=1e-6,
                               atol=1e-9 * s_np[0] ** 2)  # fmt: skip
    # a narrow sketch on this flat (noise) spectrum: Ritz values never above the truth
    narrow, _ = low_rank_curve(m, [1, 2, 4], oversample=4, power_iters=2)
    assert np.all(narrow.s <= s_np[:4] * (1 + 1e-5))
    np.testing.assert_allclose(narrow.s[0], s_np[0], rtol=1e-3)
    energy = (s_np**2).sum()
    for row in rows:
        r = row["rank"]
        assert row["removed_ideal"] == pytest.approx((s_np[:r] ** 2).sum() / energy, rel=1e-3)
        # binary16 factors: the error left is the SVD's tail to binary16 rounding
        assert row["sse_left"] == pytest.approx((s_np[r:] ** 2).sum(), rel=2e-2)
        assert row["bytes"] == low_rank_bytes(r, *m.shape) == 2 * r * sum(m.shape)
    # the leading singular vectors are the SVD's (up to sign)
    u, _, vt = np.linalg.svd(m.astype(np.float64), full_matrices=False)
    assert abs(float(fit.u[:, 0] @ u[:, 0])) == pytest.approx(1, abs=1e-3)
    assert abs(float(fit.vt[0] @ vt[0])) == pytest.approx(1, abs=1e-3)


def test_low_rank_randomised_on_a_decaying_spectrum():
    rng = np.random.default_rng(5)
    q1, _ = np.linalg.qr(rng.standard_normal((60, 20)))
    q2, _ = np.linalg.qr(rng.standard_normal((500, 20)))
    s = 2.0 ** -np.arange(20)
    m = ((q1 * s) @ q2.T).astype(np.float32)
    fit, rows = low_rank_curve(m, [1, 2, 4, 8], oversample=6, power_iters=3)
    np.testing.assert_allclose(fit.s, s[:8], rtol=1e-4)
    for row in rows:
        r = row["rank"]
        assert row["removed_ideal"] == pytest.approx((s[:r] ** 2).sum() / (s**2).sum())


def test_low_rank_exact_on_a_low_rank_matrix():
    rng = np.random.default_rng(3)
    m = (rng.standard_normal((30, 2)) @ rng.standard_normal((2, 200))).astype(np.float32)
    fit = low_rank(m, 2, oversample=2)
    left, right = fit.factors16(2)
    assert np.abs(m - left @ right).max() < 1e-2 * np.abs(m).max()
    with pytest.raises(BTFInputError):
        low_rank(m, 0)


def test_sparse_values_keep_the_largest():
    dec, ref = _pair(4)
    res = dec - ref
    sq = np.sort((res.astype(np.float64) ** 2).ravel())[::-1]
    out = sparse_values_curve(res, [0, 60, 600])
    assert [o["values"] for o in out] == [0, 10, 100]
    for o in out:
        assert o["sse_left"] == pytest.approx(sq[o["values"]:].sum())


def test_channels_layout_shares_rank_by_singular_value():
    """Per channel a texels × directions SVD; the total rank goes to the largest σ² of any
    channel (as the PCA baseline splits it)."""
    dec, ref = _pair(6)
    res = ref - dec
    h, w, nl, nv, c = res.shape
    mats = [res[..., ch].reshape(h * w, nl * nv).astype(np.float64) for ch in range(c)]
    svs = [np.linalg.svd(m, compute_uv=False) for m in mats]
    energy = sum((s**2).sum() for s in svs)
    fits, rows = low_rank_channels(res, [1, 3, 5], oversample=h * w)  # direct SVDs
    allsq = np.sort(np.concatenate([s[:5] ** 2 for s in svs]))[::-1]
    for row in rows:
        r = row["rank"]
        assert sum(row["ranks"]) == r
        assert row["removed_ideal"] == pytest.approx(allsq[:r].sum() / energy, rel=1e-5)
        assert row["sse_left"] == pytest.approx(energy - allsq[:r].sum(), rel=2e-2)
        assert row["bytes"] == 2 * r * (h * w + nl * nv)
    assert allocate_channel_ranks(fits, 0) == (0, 0, 0)
    corr = channels_correction(fits, (1, 0, 0), res.shape)
    u, s, vt = np.linalg.svd(mats[0], full_matrices=False)
    np.testing.assert_allclose(corr[..., 0].reshape(h * w, -1), s[0] * np.outer(u[:, 0], vt[0]),
                               atol=2e-3 * s[0])  # fmt: skip
    assert not corr[..., 1:].any()

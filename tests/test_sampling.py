"""BTF-driven sampling without Mitsuba: candidate lists, the codes' angular response, the
tables and the NumPy reference sampler (:mod:`sparsebtf.rendering.mitsuba.sampling`)."""

from __future__ import annotations

import numpy as np
import pytest

from sparsebtf.codec import encode
from sparsebtf.data.directions import k_nearest, tiny, ubo2014
from sparsebtf.errors import BTFInputError
from sparsebtf.rendering.mitsuba import sampling
from sparsebtf.runtime import RuntimeBTF
from sparsebtf.runtime.angular import candidate_lists, cell_of
from sparsebtf.runtime.response import angular_response, mean_log_yuv

from .conftest import smooth_btf, tiny_model


def _hemisphere(rng, n, lo=0.0):
    v = rng.normal(size=(n, 3))
    v[:, 2] = np.abs(v[:, 2]) + lo
    return v / np.linalg.norm(v, axis=1, keepdims=True)


@pytest.fixture(scope="module")
def runtime():
    model = tiny_model()
    return RuntimeBTF(encode(smooth_btf(9), model, tau=(100, 20, 20), eps=0.0, progress=False))


@pytest.mark.parametrize("dirs", [ubo2014(), tiny(13)], ids=["ubo2014", "tiny13"])
@pytest.mark.parametrize("k", [1, 2, 3, 4])
def test_candidate_lists_hold_the_k_nearest(dirs, k):
    """A query's k nearest (of a scan of every direction) are in its cell's list."""
    offsets, indices = candidate_lists(dirs, k)
    assert offsets.shape == (64 * 256 + 1,) and offsets[-1] == indices.size
    rng = np.random.default_rng(k)
    q = _hemisphere(rng, 30000)
    # and queries on cell borders (the corners of the grid), where rounding picks a cell
    e, a = np.meshgrid(np.arange(65) * (np.pi / 2) / 64, np.arange(257) * 2 * np.pi / 256 - np.pi,
                       indexing="ij")  # fmt: skip
    q = np.concatenate([q, np.stack([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)],
                                    -1).reshape(-1, 3)])  # fmt: skip
    true, _ = k_nearest(dirs.xyz, q, k)
    c = cell_of(q)
    width = int(np.diff(offsets).max())
    pos = offsets[c][:, None] + np.arange(width)[None, :]
    lists = np.where(pos < offsets[c + 1][:, None], indices[np.minimum(pos, indices.size - 1)], -1)
    found = (lists[:, :, None] == true[:, None, :]).any(axis=1)
    assert found.all(), f"{(~found.all(axis=1)).sum()} queries miss a true neighbour"
    assert np.diff(offsets).mean() < k + 4  # a few candidates, not a scan


def test_mean_log_yuv_is_the_spatial_mean_of_each_point(runtime):
    """The contraction equals the mean over each point's texels of the decoded log-YUV."""
    rt = runtime
    lx, vx = rt.coded.lights.xyz, rt.coded.views.xyz
    h, w, p = rt.meta["height"], rt.meta["width"], rt.meta["patch"]
    r, c, li, vi = (a.ravel() for a in np.meshgrid(np.arange(h), np.arange(w), np.arange(len(lx)),
                                                  np.arange(len(vx)), indexing="ij"))  # fmt: skip
    out = rt.evaluate(lx[li], vx[vi], texel=np.stack([r, c], 1), interpolation="nearest",
                      output="log_yuv", backend="numpy")  # fmt: skip
    point = r // p + rt.meta["n_rb"] * (c // p)
    ref = np.zeros((rt.meta["n_points"], len(lx), len(vx), 3))
    np.add.at(ref, (point, li, vi), out / (p * p))
    got = mean_log_yuv(rt)
    np.testing.assert_allclose(got, ref, atol=2e-6 * np.abs(ref).max())
    per_point = angular_response(rt, per_point=True)
    assert per_point.shape == (4, 13, 13) and np.all(per_point >= 0)
    np.testing.assert_allclose(angular_response(rt), per_point.mean(0), rtol=1e-6)
    np.testing.assert_allclose(angular_response(rt, chunk=3), angular_response(rt), rtol=1e-6)


def test_warps_are_mitsubas_and_invert():
    rng = np.random.default_rng(1)
    u = rng.uniform(size=(5000, 2))
    w = sampling.square_to_uniform_hemisphere(u)
    np.testing.assert_allclose(np.linalg.norm(w, axis=1), 1, atol=1e-12)
    assert np.all(w[:, 2] >= 0)
    np.testing.assert_allclose(sampling.uniform_hemisphere_to_square(w), u, atol=1e-9)
    c = sampling.square_to_cosine_hemisphere(u)
    np.testing.assert_allclose(np.linalg.norm(c, axis=1), 1, atol=1e-12)
    # equal area: uniform squares give uniform z (Archimedes), cosine ones give z² uniform
    assert abs(np.mean(w[:, 2]) - 0.5) < 0.01 and abs(np.mean(c[:, 2] ** 2) - 0.5) < 0.01


def _tables(runtime, **kw):
    rt = runtime
    return sampling.build_tables(angular_response(rt, per_point=True), rt.coded.lights.xyz,
                                 rt.coded.views.xyz, **kw)  # fmt: skip


def test_tables_are_cdfs_that_follow_the_response(runtime):
    t = _tables(runtime, grid=8)
    for mode, n in (("radiance", 13), ("importance", 13)):
        cdf = t.cdf[mode]
        assert cdf.shape == (4, n, 64) and cdf.dtype == np.float32
        assert np.all(np.diff(cdf, axis=-1) >= 0) and np.all(cdf[..., -1] == 1)
    assert t.nbytes == sampling.table_bytes(4, 13, 13, 8)
    # a response that is bright in one light bin puts most of the mass around it
    m = np.full((13, 13), 0.01)
    m[7] = 10.0
    x = tiny(13).xyz
    one = sampling.build_tables(m, x, x, "nearest", grid=16)
    pmf = np.diff(one.cdf["radiance"][0, 0], prepend=0)
    cells = np.arange(256)
    centres = sampling.square_to_uniform_hemisphere(
        np.stack([cells % 16 + 0.5, cells // 16 + 0.5], axis=1) / 16
    )
    assert np.array_equal(sampling.cell_of(centres, 16), cells)  # centres lie in their cells
    nearest_bin = k_nearest(x, centres, 1)[0][:, 0]
    assert pmf[nearest_bin == 7].sum() > 0.95
    # a zero response: uniform rows
    flat = sampling.build_tables(np.zeros((13, 13)), x, x, grid=4)
    np.testing.assert_allclose(flat.cdf["importance"][0, 3], (np.arange(16) + 1) / 16, rtol=1e-6)


def test_numpy_sampler_draws_its_pdf(runtime):
    """Histogram of the samples over the cells = the pdf integrated over them; the pdf
    integrates to one (uniform Monte Carlo) and is positive wherever cos θ > 0."""
    t = _tables(runtime, grid=8, scheme="barycentric", mix=0.3)
    rng = np.random.default_rng(2)
    n = 200_000
    known = _hemisphere(rng, n, 0.05)
    from sparsebtf.runtime import angular_weights

    idx, w = angular_weights(runtime.coded.views, known[:1].repeat(n, 0), "barycentric")
    rows = np.full(n, 2)
    wo = sampling.sample(t, "radiance", rows, idx, w, rng.uniform(size=n), rng.uniform(size=(n, 2)))
    assert np.all(wo[:, 2] >= 0)
    counts = np.bincount(sampling.cell_of(wo, 8), minlength=64) / n
    # the exact probability of each cell: the table part is pmf, the cosine part is the cosine
    # measure of the cell, estimated with many uniform points
    u = rng.uniform(size=(400_000, 2))
    d = sampling.square_to_uniform_hemisphere(u)
    c = sampling.cell_of(d, 8)
    p = sampling.pdf(t, "radiance", np.full(u.shape[0], 2), idx[:1].repeat(u.shape[0], 0),
                     w[:1].repeat(u.shape[0], 0), d)  # fmt: skip
    expect = np.bincount(c, weights=p * 2 * np.pi, minlength=64) / u.shape[0]
    assert abs(expect.sum() - 1) < 0.01
    sigma = np.sqrt(expect / n) + 1e-4
    assert np.all(np.abs(counts - expect) < 5 * sigma + 0.01 * expect)
    assert np.all(p[d[:, 2] > 1e-3] > 0)


def test_component_choice_follows_the_weights():
    rng = np.random.default_rng(3)
    w = np.tile([[0.5, 0.3, 0.2, 0.0]], (100_000, 1))
    a, ur = sampling.component(w, rng.uniform(size=100_000))
    np.testing.assert_allclose(np.bincount(a, minlength=4) / 1e5, [0.5, 0.3, 0.2, 0.0], atol=0.01)
    assert ur.min() >= 0 and ur.max() < 1 and abs(ur.mean() - 0.5) < 0.01


def test_bad_tables_are_refused():
    x = tiny(13).xyz
    with pytest.raises(BTFInputError, match="angular response"):
        sampling.build_tables(np.ones((12, 13)), x, x)
    with pytest.raises(BTFInputError, match="grid"):
        sampling.build_tables(np.ones((13, 13)), x, x, grid=1)
    with pytest.raises(BTFInputError, match="mix"):
        sampling.build_tables(np.ones((13, 13)), x, x, mix=0.0)

"""The compiled lookup (runtime/wavefront.py, DirectionIndex) tied to the NumPy reference:
grouping, both loops of Eq. 6, every scheme, domain, output, level of detail and dtype."""

import itertools

import numpy as np
import pytest

from sparsebtf.codec import encode
from sparsebtf.data.directions import k_nearest, ubo2014
from sparsebtf.runtime import DirectionIndex, RuntimeBTF, angular_weights, kernels
from sparsebtf.runtime.angular import SCHEMES
from sparsebtf.runtime.compact import DENSE_FRACTION, compact_layout
from sparsebtf.runtime.grouping import _group_numpy, group_by_point
from sparsebtf.runtime.wavefront import grouped_pays, separable_sums

from .conftest import smooth_btf, tiny_model

numba_only = pytest.mark.skipif(not kernels.HAVE_NUMBA, reason="numba is not installed")


@pytest.fixture(scope="module")
def coded():
    return encode(smooth_btf(9), tiny_model(), tau=(40, 8, 8), eps=0.0, progress=False)


def _dirs(rng, n, low=0.05):
    el = rng.uniform(low, np.pi / 2, n)
    az = rng.uniform(-np.pi, np.pi, n)
    return np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], axis=1)


@pytest.mark.parametrize("width", [1, 3, 32])
def test_groups_hold_every_query_once_each_of_one_point(width):
    rng = np.random.default_rng(0)
    pts = rng.integers(0, 7, 500)
    pts[pts == 4] = 5  # a point without queries
    order, starts = group_by_point(pts, 7, width)
    assert np.array_equal(np.sort(order), np.arange(pts.size))
    assert starts[0] == 0 and starts[-1] == pts.size
    sizes = np.diff(starts)
    assert sizes.min() >= 1 and sizes.max() <= width
    for a, b in itertools.pairwise(starts):
        assert np.unique(pts[order[a:b]]).size == 1
        assert np.all(np.diff(order[a:b]) > 0)  # stable within a point
    ref = _group_numpy(pts, width)
    assert np.array_equal(order, ref[0]) and np.array_equal(starts, ref[1])


@pytest.mark.parametrize("k", [1, 2, 3, 4, 8])
@pytest.mark.parametrize("which", ["ubo2014", "tiny"])
def test_direction_index_finds_the_same_neighbours_as_the_full_scan(k, which, coded):
    dirs = ubo2014() if which == "ubo2014" else coded.lights
    rng = np.random.default_rng(k)
    q = np.concatenate([
        _dirs(rng, 3000, 0.0),
        dirs.xyz,  # sampled directions: exact hits and tied neighbours
        -_dirs(rng, 50),  # below the horizon: the full scan
        [[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]],  # horizon, pole, φ = −π/2
    ])  # fmt: skip
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    idx, d2 = DirectionIndex(dirs, k).k_nearest(q)
    ref_idx, ref_d2 = k_nearest(dirs.xyz, q, k)
    assert np.array_equal(idx, ref_idx)
    np.testing.assert_array_equal(d2, ref_d2)


@pytest.mark.parametrize("scheme", SCHEMES)
def test_angular_weights_with_a_table_equal_the_scan(scheme, coded):
    rng = np.random.default_rng(1)
    q = _dirs(rng, 400)
    k = 4 if scheme == "gaussian" else None
    kk = {"nearest": 1, "linear": 2, "barycentric": 3, "gaussian": 4}[scheme]
    q[:7] = coded.lights.xyz[:7] * 3.0  # sampled directions (exact hits), not unit length
    a = angular_weights(coded.lights, q, scheme, k)
    b = angular_weights(coded.lights, q, scheme, k, table=DirectionIndex(coded.lights, kk))
    assert np.array_equal(a[0], b[0])
    if scheme in ("gaussian", "barycentric"):  # exp, the row sum, Cramer's rule against
        # NumPy's exp, sum and LU solve: the same weights to rounding
        np.testing.assert_allclose(b[1], a[1], rtol=1e-9, atol=1e-12)
    else:
        np.testing.assert_array_equal(a[1], b[1])


@numba_only
def test_the_fused_weights_find_the_scans_neighbours_on_cell_borders():
    """The compiled weights place a query in its grid cell with an approximate float32
    atan2 (within 5e-7 rad): queries on every elevation and azimuth border of the grid, and
    near them, still get the full scan's neighbours."""
    from sparsebtf.runtime.angular import _atan2f, _atan_poly_f32

    rng = np.random.default_rng(4)
    y, x = rng.normal(size=(2, 20000)).astype(np.float32)
    y[:4], x[:4] = [0.0, 1.0, -1.0, 0.0], [1.0, 0.0, 0.0, -1.0]  # the axes
    got = np.array([_atan2f(a, b, _atan_poly_f32()) for a, b in zip(y, x, strict=True)])
    assert np.max(np.abs(got - np.arctan2(y.astype(np.float64), x))) < 5e-7
    dirs = ubo2014()
    near = np.array([-1e-6, -1e-9, 0.0, 1e-9, 1e-6])  # float32 cells err by up to ~3e-7 rad
    el = (np.arange(65) * (np.pi / 2) / 64)[:, None] + near
    az = (np.arange(256) * (2 * np.pi) / 256 - np.pi)[:, None] + near
    e, a = np.meshgrid(el.ravel(), az.ravel()[::3], indexing="ij")
    e = np.clip(e, 0.0, np.pi / 2)
    q = np.stack([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)], -1).reshape(-1, 3)
    for k, scheme in ((1, "nearest"), (2, "linear"), (3, "barycentric"), (4, "gaussian")):
        idx, _ = DirectionIndex(dirs, k).weights(q, scheme)
        ref, _ = k_nearest(dirs.xyz, q / np.linalg.norm(q, axis=1, keepdims=True), k)
        assert np.array_equal(idx, ref)


@pytest.mark.parametrize("table", [False, True])
def test_bad_query_directions_are_refused_with_or_without_a_table(coded, table):
    from sparsebtf.errors import BTFInputError

    q = _dirs(np.random.default_rng(2), 10)
    q[4] = 0.0
    q[6, 1] = np.nan
    index = DirectionIndex(coded.lights, 2) if table else None
    with pytest.raises(BTFInputError, match=r"direction 4 is zero or not finite \(2 such"):
        angular_weights(coded.lights, q, "linear", table=index)


def _sums_inputs(coded, n, rng, scheme="linear"):
    rt = RuntimeBTF(coded)
    uv = rng.uniform(-1, 2, (n, 2))
    pts, i1, i2 = rt._texels(uv, None, n)
    li, lw = angular_weights(coded.lights, _dirs(rng, n), scheme)
    vi, vw = angular_weights(coded.views, _dirs(rng, n), scheme)
    return rt, (pts, i1, i2, li, lw, vi, vw)


@numba_only
@pytest.mark.parametrize("loop", ["grouped", "query"])
@pytest.mark.parametrize("scheme", SCHEMES)
@pytest.mark.parametrize("width", [1, 5, 32])
def test_both_loops_equal_the_reference_sum(coded, loop, scheme, width):
    rng = np.random.default_rng(width)
    n = 300
    rt, (pts, i1, i2, li, lw, vi, vw) = _sums_inputs(coded, n, rng, scheme)
    groups = group_by_point(pts, coded.n_points, width)
    for ch in "YUV":
        arr = rt._channels[ch]
        full = float(rt.tau[ch])
        # every mode as a whole row (0), lists wherever a point leaves columns unused (1),
        # and the default: both kinds of factor in one lookup
        layouts = [compact_layout(arr["offsets"], arr["locations"], arr["values"], (4, 4, 13, 13),
                                  f)
                   for f in (0.0, 1.0, DENSE_FRACTION)]  # fmt: skip
        for tau, lay in itertools.product(
                (np.full(n, full), np.full(n, 3.0), rng.uniform(0, full, n),
                 rng.integers(0, int(full) + 1, n).astype(float)), layouts):  # fmt: skip
            ref = kernels.separable_sum(arr, pts, i1, i2, li, lw, vi, vw, tau, "numpy")
            got = separable_sums(arr, pts, i1, i2, li, lw, vi, vw, tau, groups, loop, width,
                                 layout=lay)  # fmt: skip
            scale = np.abs(ref).max()
            np.testing.assert_allclose(got, ref, rtol=0, atol=2e-6 * scale)
    assert np.abs(ref).max() > 0
    assert any(lay.o3[-1] < 13 * coded.n_points for lay in layouts)  # some lists were short


@numba_only
def test_the_loop_choice_follows_the_terms():
    """The grouped loop pays for a channel with many queries per point, not for a query
    alone on its point."""
    ch = {"offsets": np.array([0, 885, 1770])}
    assert grouped_pays(ch, np.full(100, 885.0), 32)
    assert grouped_pays(ch, np.full(100, 64.0), 32)
    assert not grouped_pays(ch, np.full(100, 885.0), 1)


@numba_only
@pytest.mark.parametrize("domain", ["standardized", "log"])
@pytest.mark.parametrize("scheme", SCHEMES)
def test_evaluate_compiled_equals_numpy(coded, domain, scheme):
    rng = np.random.default_rng(7)
    n = 400
    uv = rng.uniform(-2, 3, (n, 2))
    wi, wo = _dirs(rng, n), _dirs(rng, n)
    wi[:5] = coded.lights.xyz[:5]  # measured directions too
    for dtype in (np.float32, np.float64):
        rt = RuntimeBTF(coded, dtype=dtype)
        tol = 1e-5 if dtype is np.float32 else 1e-9
        frac = rng.uniform(0, 1, (n, 3)) * np.array([rt.tau[c] for c in "YUV"])
        for kw in ({}, {"tau": frac}, {"tau": "10,3,2"}, {"output": "log_yuv"},
                   {"release_matrix": True}):  # fmt: skip
            a = rt.evaluate(wi, wo, uv=uv, interpolation=scheme, domain=domain,
                            backend="numpy", **kw)  # fmt: skip
            b = rt.evaluate(wi, wo, uv=uv, interpolation=scheme, domain=domain,
                            backend="numba", **kw)  # fmt: skip
            np.testing.assert_allclose(b, a, rtol=tol, atol=tol * np.abs(a).max())


@numba_only
def test_evaluate_compiled_without_a_bound_and_with_every_group_shape(coded):
    """A material without a bound (older files), and queries that all land on one point or
    one per point: the fused finish and the grouping agree with the reference."""
    rt = RuntimeBTF(coded)
    rt._bound = None
    rng = np.random.default_rng(3)
    n = 200
    wi, wo = _dirs(rng, n), _dirs(rng, n)
    for texel in (np.zeros((n, 2), dtype=np.int64),
                  np.stack([rng.integers(0, 8, n), rng.integers(0, 8, n)], 1)):  # fmt: skip
        a = rt.evaluate(wi, wo, texel=texel, backend="numpy")
        b = rt.evaluate(wi, wo, texel=texel, backend="numba")
        np.testing.assert_allclose(b, a, rtol=1e-5)
    t0 = np.zeros((1, 2), dtype=np.int64)
    np.testing.assert_allclose(rt.evaluate(wi[:1], wo[:1], texel=t0, backend="numba"),
                               rt.evaluate(wi[:1], wo[:1], texel=t0, backend="numpy"),
                               rtol=1e-5)  # fmt: skip


@numba_only
def test_the_finishing_exp_is_within_4e16_of_numpys():
    """The runtime's exp (plain arithmetic, so it vectorises) against np.exp over the range a
    decoded log value takes and the clamps at both ends; NaN stays NaN."""
    from sparsebtf._numba import numba as nb
    from sparsebtf.runtime.finish import _exp

    f = nb.njit(lambda a: np.array([_exp(t) for t in a]))
    x = np.concatenate([np.random.default_rng(5).uniform(-60.0, 12.0, 20000),
                        [0.0, -0.0, 1e-300, np.log(2.0), -np.log(2.0) / 2, 700.0, -700.0]])
    np.testing.assert_allclose(f(x), np.exp(x), rtol=4e-16, atol=0)
    lo, hi, nan = f(np.array([-800.0, 800.0, np.nan]))
    np.testing.assert_allclose([lo, hi], np.exp([-708.0, 709.0]), rtol=4e-16, atol=0)
    assert np.isnan(nan)


@numba_only
@pytest.mark.parametrize("std_mode", ["shared", "per_channel"])
@pytest.mark.parametrize("scheme", SCHEMES)
def test_texel_groups_equal_numpy(std_mode, scheme):
    """A texel with many queries gets groups of its own: a group's pair sums are shared by
    its lanes and kept for the next group on that texel, also across groups that keep only
    part of the list (per-query τ); the other queries share groups — against the reference,
    with shared and per-channel statistics."""
    from sparsebtf.runtime.grouping import TEXEL_GROUPING, group_queries

    coded = encode(smooth_btf(9), tiny_model(), tau=(40, 8, 8), eps=0.0, std_mode=std_mode,
                   progress=False)  # fmt: skip
    rt = RuntimeBTF(coded)
    assert rt._mean.shape[0] == (3 if std_mode == "per_channel" else 1)
    rng = np.random.default_rng(11)
    n = 2400
    texel = rng.integers(0, [coded.height, coded.width], (n, 2))  # ~12 a texel: shared groups
    texel[:1600] = (3, 5)  # one texel with many groups
    texel[1600 : 1600 + TEXEL_GROUPING] = (6, 1)  # one at least at the threshold
    wi, wo = _dirs(rng, n), _dirs(rng, n)
    pts, i1, i2 = rt._texels(None, texel, n)
    order, starts = group_queries(pts, i1, i2, coded.n_points, coded.patch)
    one = [np.unique(texel[order[a:b]], axis=0).shape[0] == 1
           for a, b in itertools.pairwise(starts)]  # fmt: skip
    assert 0 < sum(one) < len(one)  # both kinds of group
    tau = np.where(rng.uniform(size=(n, 3)) < 0.8, 1.0, rng.uniform(size=(n, 3)))
    for kw in ({}, {"tau": tau * np.array([rt.tau[c] for c in "YUV"])}):
        a = rt.evaluate(wi, wo, texel=texel, interpolation=scheme, backend="numpy", **kw)
        b = rt.evaluate(wi, wo, texel=texel, interpolation=scheme, backend="numba", **kw)
        np.testing.assert_allclose(b, a, rtol=1e-5, atol=1e-5 * np.abs(a).max())


@numba_only
def test_texel_groups_hold_one_texel_and_the_rest_share():
    """group_queries: every query once, every group of one point and at most GROUP wide; a
    texel with TEXEL_GROUPING queries or more in groups of its own, every other texel's
    queries in shared groups; below the threshold everywhere, the point groups."""
    from sparsebtf.runtime.grouping import GROUP, TEXEL_GROUPING, group_queries

    rng = np.random.default_rng(3)
    n_points, patch = 6, 4
    pts = rng.integers(0, n_points, 4000)
    i1, i2 = rng.integers(0, patch, (2, pts.size))
    pts[:900], i1[:900], i2[:900] = 2, 1, 3  # a heavy texel
    order, starts = group_queries(pts, i1, i2, n_points, patch)
    assert np.array_equal(np.sort(order), np.arange(pts.size))
    key = (pts * patch + i1) * patch + i2
    heavy = np.bincount(key, minlength=n_points * patch**2) >= TEXEL_GROUPING
    for a, b in itertools.pairwise(starts):
        g = order[a:b]
        assert 0 < g.size <= GROUP and np.unique(pts[g]).size == 1
        if heavy[key[g]].any():  # a heavy texel's group holds that texel alone
            assert np.unique(key[g]).size == 1
    few = rng.integers(0, n_points * patch**2, 50)  # no texel at the threshold: the point
    p2 = few // patch**2  # groups (queries in texel order within a point)
    o2, s2 = group_queries(p2, few // patch % patch, few % patch, n_points, patch)
    ref = group_by_point(p2, n_points)
    assert np.array_equal(s2, ref[1]) and np.array_equal(p2[o2], p2[ref[0]])


@numba_only
def test_the_compiled_texel_pass_names_the_first_bad_query(coded):
    """locate_nb stands in for query_texels and PatchGrid.locate: the same points and texels,
    and a bad query anywhere in the batch gets query_texels' message with its index."""
    from sparsebtf.errors import BTFInputError
    from sparsebtf.points.grid import PatchGrid
    from sparsebtf.runtime.decoder import query_texels
    from sparsebtf.runtime.grouping import locate_nb

    rng = np.random.default_rng(9)
    h, w, p = coded.height, coded.width, coded.patch
    uv = rng.uniform(-3, 3, (300, 2))
    uv[:3] = [[0.0, 0.0], [1.0 - 1e-17, 0.999999999], [-1e-300, 2.0]]  # edges of the wrap
    texel = rng.integers(0, [h, w], (300, 2))
    for t, from_uv in ((uv, True), (texel, False)):
        pts, i1, i2, _, n_bad = locate_nb(t, h, w, p, from_uv)
        row, col = query_texels(t if from_uv else None, None if from_uv else t, h, w)
        ref = PatchGrid(h, w, p).locate(row, col)
        assert n_bad == 0 and all(np.array_equal(a, b) for a, b in zip((pts, i1, i2), ref,
                                                                          strict=True))
    rt = RuntimeBTF(coded)
    wi = _dirs(rng, 300)
    uv[[123, 200]] = np.nan
    texel[57] = (h, 0)
    for kw, msg in (({"uv": uv}, "uv 123 is not finite"),
                    ({"texel": texel}, rf"texel 57 = \({h}, 0\) is outside")):  # fmt: skip
        with pytest.raises(BTFInputError, match=msg):
            rt.evaluate(wi, wi, **kw)

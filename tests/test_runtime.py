"""Runtime decoder (§3.4): Eq. 5 vs Eq. 4, Eq. 6 vs separate bins, level of detail, uv wrapping."""

import numpy as np
import pytest

from sparsebtf.codec import encode
from sparsebtf.data.directions import ubo2014
from sparsebtf.errors import BTFInputError
from sparsebtf.runtime import (
    RuntimeBTF,
    angular_weights,
    coded_btf_view,
    decode_points_eq5,
    kernels,
    neighbour_table,
    texels_from_uv,
)

from .conftest import smooth_btf, tiny_model

BACKENDS = ["numpy"] + (["numba"] if kernels.HAVE_NUMBA else [])


@pytest.fixture(scope="module")
def coded():
    model = tiny_model()
    return encode(smooth_btf(9), model, tau=(40, 8, 8), eps=0.0, progress=False)


@pytest.fixture(scope="module")
def rt64(coded):
    return RuntimeBTF(coded, dtype=np.float64)


def _random_dirs(rng, n):
    el = rng.uniform(0.05, np.pi / 2, n)
    az = rng.uniform(-np.pi, np.pi, n)
    return np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], axis=1)


@pytest.mark.parametrize("backend", BACKENDS)
def test_eq5_equals_eq4_at_sampled_directions(coded, rt64, backend):
    rng = np.random.default_rng(0)
    n = 60
    r, c = rng.integers(0, 8, n), rng.integers(0, 8, n)
    li, vi = rng.integers(0, 13, n), rng.integers(0, 13, n)
    got = rt64.evaluate(
        coded.lights.xyz[li], coded.views.xyz[vi], texel=np.stack([r, c], 1),
        interpolation="nearest", backend=backend,
    )  # fmt: skip
    ref = coded_btf_view(coded).read(slice(None), slice(None), slice(None), slice(None))
    np.testing.assert_allclose(got, ref[r, c, li, vi], rtol=2e-5, atol=1e-7)
    # float32 renderer precision stays within 1e-4 relative
    got32 = RuntimeBTF(coded).evaluate(
        coded.lights.xyz[li], coded.views.xyz[vi], texel=np.stack([r, c], 1),
        interpolation="nearest", backend=backend,
    )  # fmt: skip
    np.testing.assert_allclose(got32, ref[r, c, li, vi], rtol=1e-4, atol=1e-6)


@pytest.mark.parametrize("scheme", ["nearest", "linear", "barycentric"])
def test_interpolation_at_sampled_direction_returns_sample(coded, rt64, scheme):
    rng = np.random.default_rng(1)
    n = 40
    tex = np.stack([rng.integers(0, 8, n), rng.integers(0, 8, n)], 1)
    li, vi = rng.integers(0, 13, n), rng.integers(0, 13, n)
    wi, wo = coded.lights.xyz[li], coded.views.xyz[vi]
    near = rt64.evaluate(wi, wo, texel=tex, interpolation="nearest")
    for domain in ("standardized", "log"):
        got = rt64.evaluate(wi, wo, texel=tex, interpolation=scheme, domain=domain)
        np.testing.assert_allclose(got, near, rtol=1e-9, atol=1e-12)


def _separate_bins(coded, tex, li, lw, vi, vw, domain):
    """Decode every neighbour pair separately (codec Eq. 5), then blend in ``domain``."""
    p = coded.patch
    pts = tex[:, 0] // p + (coded.height // p) * (tex[:, 1] // p)
    i1, i2 = tex[:, 0] % p, tex[:, 1] % p
    mu, sd = coded.stats.mean, coded.stats.std
    out = np.zeros((tex.shape[0], 3))
    for q in range(tex.shape[0]):
        for c, ch in enumerate(coded.channels):
            z = decode_points_eq5(coded, ch, [pts[q]], li[q], vi[q])[0, i1[q], i2[q]]  # (kl, kv)
            s = 0 if mu.shape[2] == 1 else c
            m, d = mu[np.ix_(li[q], vi[q])][..., s], sd[np.ix_(li[q], vi[q])][..., s]
            w = np.outer(lw[q], vw[q])
            if domain == "log":
                out[q, c] = np.sum(w * (d * z + m))
            else:
                out[q, c] = np.sum(w * z) * np.sum(w * d) + np.sum(w * m)
    return out


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("scheme", ["linear", "barycentric", "gaussian"])
@pytest.mark.parametrize("domain", ["standardized", "log"])
def test_coefficient_space_equals_separate_reconstructions(coded, rt64, scheme, domain, backend):
    rng = np.random.default_rng(2)
    n = 25
    tex = np.stack([rng.integers(0, 8, n), rng.integers(0, 8, n)], 1)
    wi, wo = _random_dirs(rng, n), _random_dirs(rng, n)
    got = rt64.evaluate(
        wi, wo, texel=tex, interpolation=scheme, domain=domain, output="log_yuv", backend=backend
    )
    li, lw = angular_weights(coded.lights, wi, scheme)
    vi, vw = angular_weights(coded.views, wo, scheme)
    ref = _separate_bins(coded, tex, li, lw, vi, vw, domain)
    np.testing.assert_allclose(got, ref, rtol=0, atol=1e-6)


@pytest.mark.skipif(not kernels.HAVE_NUMBA, reason="numba is not installed")
def test_numba_equals_numpy(coded):
    rt = RuntimeBTF(coded)
    rng = np.random.default_rng(3)
    n = 500
    uv = rng.uniform(-2, 3, (n, 2))
    wi, wo = _random_dirs(rng, n), _random_dirs(rng, n)
    for domain in ("standardized", "log"):
        a = rt.evaluate(wi, wo, uv=uv, domain=domain, interpolation="gaussian", backend="numpy")
        b = rt.evaluate(wi, wo, uv=uv, domain=domain, interpolation="gaussian", backend="numba")
        np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-7)


def test_tau_truncation_keeps_the_largest_coefficients(coded):
    rt = RuntimeBTF(coded)
    low = rt.with_tau({"Y": 10, "U": 3, "V": 2})
    assert low.tau == {"Y": 10, "U": 3, "V": 2}
    for ch, t in low.tau.items():
        full, cut = coded.codes[ch], low.coded.codes[ch]
        assert np.array_equal(cut.counts, np.minimum(full.counts, t))
        for i in range(full.n_points):
            loc, val = full.point(i)
            keep = np.argsort(-np.abs(val), kind="stable")[:t]
            kl, kv = cut.point(i)
            assert {tuple(x) for x in loc[keep]} == {tuple(x) for x in kl}
            np.testing.assert_array_equal(np.sort(val[keep]), np.sort(kv))
            # the kept ones are at least as large as every dropped one
            dropped = np.delete(np.abs(val), keep)
            assert dropped.size == 0 or np.abs(kv).min() >= dropped.max()
    # the run-time cap gives the same values as load-time truncation
    rng = np.random.default_rng(4)
    n = 100
    uv, wi, wo = rng.uniform(0, 1, (n, 2)), _random_dirs(rng, n), _random_dirs(rng, n)
    np.testing.assert_allclose(
        rt.evaluate(wi, wo, uv=uv, tau={"Y": 10, "U": 3, "V": 2}),
        low.evaluate(wi, wo, uv=uv),
        rtol=1e-6,
    )
    # fractions of the coded tau: 0.25 of (40, 8, 8)
    assert rt.with_tau(0.25).tau == {"Y": 10, "U": 2, "V": 2}
    with pytest.raises(BTFInputError, match="cannot raise tau"):
        low.with_tau(20)
    with pytest.raises(BTFInputError, match="exceeds the loaded tau"):
        low.evaluate(wi, wo, uv=uv, tau=20)


@pytest.mark.parametrize("domain", ["standardized", "log"])
def test_per_query_tau_is_each_query_at_its_own_tau(coded, domain):
    """A per-query τ array equals evaluating every query alone at its τ (integer τ), is
    linear between integers in the sums (fractional τ fades in the next coefficient), and the
    numba kernels agree with the NumPy reference."""
    rt = RuntimeBTF(coded)
    rng = np.random.default_rng(11)
    n = 60
    uv, wi, wo = rng.uniform(0, 1, (n, 2)), _random_dirs(rng, n), _random_dirs(rng, n)
    full = np.array([rt.tau[ch] for ch in "YUV"])
    ints = rng.integers(1, full + 1, (n, 3))
    got = rt.evaluate(wi, wo, uv=uv, tau=ints, domain=domain, backend="numpy")
    for q in range(0, n, 7):
        one = rt.evaluate(wi[q : q + 1], wo[q : q + 1], uv=uv[q : q + 1], domain=domain,
                          tau=dict(zip("YUV", ints[q].tolist(), strict=True)))  # fmt: skip
        np.testing.assert_allclose(got[q], one[0], rtol=1e-6)
    # (n,) applies one τ to every channel
    same = rng.integers(1, full.min() + 1, n)
    np.testing.assert_allclose(
        rt.evaluate(wi, wo, uv=uv, tau=same, domain=domain, backend="numpy"),
        rt.evaluate(wi, wo, uv=uv, tau=np.repeat(same[:, None], 3, 1), domain=domain,
                    backend="numpy"), rtol=1e-6)  # fmt: skip
    # fractional τ: the log-YUV value is the linear blend of the two integer levels around it
    lo = rng.integers(1, full, (n, 3))
    t = rng.uniform(0, 1, (n, 1))
    logs = [rt.evaluate(wi, wo, uv=uv, tau=x, domain=domain, output="log_yuv", backend="numpy")
            for x in (lo, lo + 1, lo + t)]  # fmt: skip
    blend = (1 - t) * logs[0].astype(np.float64) + t * logs[1]
    np.testing.assert_allclose(logs[2], blend, rtol=1e-5, atol=1e-5)
    assert np.abs(logs[1] - logs[0]).max() > 1e-3  # the levels differ
    if kernels.HAVE_NUMBA:
        frac = rng.uniform(0, 1, (n, 3)) * full
        a = rt.evaluate(wi, wo, uv=uv, tau=frac, domain=domain, backend="numpy")
        b = rt.evaluate(wi, wo, uv=uv, tau=frac, domain=domain, backend="numba")
        np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-7)
    with pytest.raises(BTFInputError, match=r"query 3, channel U: .* not in \[0, "):
        bad = ints.astype(float)
        bad[3, 1] = full[1] + 0.5
        rt.evaluate(wi, wo, uv=uv, tau=bad)
    with pytest.raises(BTFInputError, match="shape"):
        rt.evaluate(wi, wo, uv=uv, tau=np.ones((n, 2)))


def test_uv_wraps_for_tiling(coded):
    row, col = texels_from_uv(np.array([[0, 0], [0.999, 0.5], [1.0, 1.0], [-0.001, -0.5]]), 8, 8)
    assert col.tolist() == [0, 7, 0, 7]
    assert row.tolist() == [0, 4, 0, 4]
    rt = RuntimeBTF(coded)
    rng = np.random.default_rng(5)
    n = 64
    uv = rng.uniform(0, 1, (n, 2))
    wi, wo = _random_dirs(rng, n), _random_dirs(rng, n)
    base = rt.evaluate(wi, wo, uv=uv)
    for shift in ([1, 0], [0, 1], [-1, -1], [3, -2]):
        np.testing.assert_array_equal(rt.evaluate(wi, wo, uv=uv + shift), base)
    # uv and the texel it names agree
    r, c = texels_from_uv(uv, 8, 8)
    np.testing.assert_array_equal(rt.evaluate(wi, wo, texel=np.stack([r, c], 1)), base)


def test_flat_arrays_reproduce_a_lookup(coded):
    """The documented renderer arrays are enough to evaluate Eq. 6 by hand."""
    rt = RuntimeBTF(coded)
    a = rt.arrays()
    assert a["values_Y"].dtype == np.float32 and a["locations_Y"].dtype == np.uint32
    assert a["offsets_Y"].shape == (coded.n_points + 1,)
    assert a["dict3_Y"].shape == (3, 13, 13) and a["mean"].shape == (1, 13, 13)
    assert a["neighbours_lights"].shape == (64, 256, 8)
    wi, wo = np.array([[0.3, 0.2, 0.9]]), np.array([[-0.4, 0.1, 0.8]])
    row, col = 5, 2
    li, lw = angular_weights(a["lights_xyz"], wi, "linear")
    vi, vw = angular_weights(a["views_xyz"], wo, "linear")
    p = row // 4 + 2 * (col // 4)
    log = []
    for ch in "YUV":
        k = a[f"membership_{ch}"][p]
        s0, s1 = a[f"offsets_{ch}"][p], a[f"offsets_{ch}"][p + 1]
        x = 0.0
        for s in range(s0, s1):
            code = int(a[f"locations_{ch}"][s])
            l1, l2, l3, l4 = code & 255, (code >> 8) & 255, (code >> 16) & 255, code >> 24
            g3 = sum(lw[0, j] * a[f"dict3_{ch}"][k, li[0, j], l3] for j in range(2))
            g4 = sum(vw[0, j] * a[f"dict4_{ch}"][k, vi[0, j], l4] for j in range(2))
            x += (a[f"values_{ch}"][s] * a[f"dict1_{ch}"][k, row % 4, l1]
                  * a[f"dict2_{ch}"][k, col % 4, l2] * g3 * g4)  # fmt: skip
        w = np.outer(lw[0], vw[0])
        sel = np.ix_([0], li[0], vi[0])
        log.append(x * np.sum(w * a["std"][sel][0]) + np.sum(w * a["mean"][sel][0]))
    bound = np.sum(np.outer(lw[0], vw[0]) * a["bound"][np.ix_(li[0], vi[0])])
    rgb = np.exp(np.minimum(a["yuv_to_rgb"] @ np.array(log), bound)) - rt.meta["eps"]
    got = rt.evaluate(wi, wo, texel=np.array([[row, col]]))
    np.testing.assert_allclose(got[0], rgb, rtol=1e-5)


def test_angular_weights_schemes():
    d = ubo2014()
    rng = np.random.default_rng(6)
    q = _random_dirs(rng, 2000)
    for scheme in ("nearest", "linear", "barycentric", "gaussian"):
        idx, w = angular_weights(d, q, scheme)
        np.testing.assert_allclose(w.sum(axis=1), 1.0, atol=1e-12)
        assert (w >= 0).all()
        nn, _ = d.nearest(q, idx.shape[1])
        np.testing.assert_array_equal(idx, nn)
    # the release's 2-NN formula
    idx, w = angular_weights(d, q, "linear")
    dist = np.linalg.norm(q[:, None, :] - d.xyz[idx], axis=2)
    np.testing.assert_allclose(w[:, 0], 0.5 + 0.5 * (dist[:, 1] - dist[:, 0]) / dist[:, 1])
    # barycentric reproduces a point inside its triangle
    idx, _ = angular_weights(d, q[:1], "barycentric")
    tri = d.xyz[idx[0]]
    inside = tri.T @ np.array([0.5, 0.3, 0.2])
    i2, w2 = angular_weights(d, inside[None], "barycentric")
    np.testing.assert_allclose(w2[0][np.argsort(i2[0])], np.array([0.5, 0.3, 0.2])[np.argsort(idx[0])], atol=1e-9)  # noqa: E501
    # a sharp Gaussian is the nearest bin
    _, wg = angular_weights(d, q, "gaussian", k=4, beta=1e6)
    assert np.all(wg[:, 0] > 0.999)
    with pytest.raises(BTFInputError, match="unknown interpolation"):
        angular_weights(d, q, "cubic")
    with pytest.raises(BTFInputError, match="uses k = 2"):
        angular_weights(d, q, "linear", k=3)
    with pytest.raises(BTFInputError, match="direction 1 is zero"):
        angular_weights(d, np.array([[0, 0, 1.0], [0, 0, 0]]), "linear")


def test_neighbour_table_contains_true_neighbours():
    d = ubo2014()
    table = neighbour_table(d)
    rng = np.random.default_rng(7)
    q = _random_dirs(rng, 20000)
    el = np.arcsin(np.clip(q[:, 2], -1, 1))
    az = np.arctan2(q[:, 1], q[:, 0])
    e = np.minimum((el / (np.pi / 2) * 64).astype(int), 63)
    a = np.minimum(((az + np.pi) / (2 * np.pi) * 256).astype(int), 255)
    cand = table[e, a].astype(np.int64)  # (n, 8)
    true3, _ = d.nearest(q, 3)
    found = (cand[:, :, None] == true3[:, None, :]).any(axis=1).all(axis=1)
    assert found.all(), f"{(~found).sum()} of {q.shape[0]} queries miss a true neighbour"


def test_runtime_rejects_bad_input(coded):
    rt = RuntimeBTF(coded)
    wi = np.array([[0, 0, 1.0]])
    with pytest.raises(BTFInputError, match="outside the 8x8"):
        rt.evaluate(wi, wi, texel=np.array([[8, 0]]))
    with pytest.raises(BTFInputError, match="exactly one of uv and texel"):
        rt.evaluate(wi, wi)
    with pytest.raises(BTFInputError, match="domain"):
        rt.evaluate(wi, wi, uv=np.zeros((1, 2)), domain="rgb")
    with pytest.raises(BTFInputError, match="uv 0 is not finite"):
        rt.evaluate(wi, wi, uv=np.array([[np.nan, 0]]))
    with pytest.raises(BTFInputError, match="1 texels for 2"):
        rt.evaluate(np.repeat(wi, 2, 0), np.repeat(wi, 2, 0), uv=np.zeros((1, 2)))
    with pytest.raises(BTFInputError, match="fractional tau"):
        RuntimeBTF(coded, tau=1.5)


def test_lod_rule():
    """footprint_fraction: full τ up to one texel per pixel, 1/ρ² beyond, floored; lod_tau keeps
    at least one coefficient and never exceeds the cap; the ray cone grows with distance and
    grazing angle and shrinks with larger texels."""
    from sparsebtf.runtime.lod import (
        MIN_FRACTION,
        cone_texels_per_pixel,
        footprint_fraction,
        lod_tau,
    )

    f = footprint_fraction(np.array([0.2, 1.0, 1.2, 100.0]))
    np.testing.assert_allclose(f, [1.0, 1.0, max(1 / 1.44, MIN_FRACTION), MIN_FRACTION])
    t = lod_tau({"Y": 885, "U": 64, "V": 1}, np.array([1.0, 0.5, 0.001]))
    np.testing.assert_allclose(t, [[885, 64, 1], [442.5, 32, 1], [1, 1, 1]])
    rho = cone_texels_per_pixel(np.array([1.0, 2.0, 1.0, 1.0]), 0.01, np.array([1, 1, 0.25, 1]),
                                np.array([1, 1, 1, 4.0]), 1.0, 1 / 100**2)  # fmt: skip
    np.testing.assert_allclose(rho, [1.0, 2.0, 2.0, 0.5])

"""Highlight corrections in the decoders (issue 46): the runtime's NumPy and numba paths and
the Mitsuba plugin's Dr.Jit and host lookups all return max(decode + Σ_ab wl_a wv_b c +
lobe(x, ω_i, ω_o), 0) with their own angular weights and the query's own directions, the
references being :func:`sparsebtf.learning.highlights.correction` and
:func:`~sparsebtf.learning.highlights.lobe_corrections`; without a store nothing changes."""

from __future__ import annotations

import importlib.util
from dataclasses import replace

import numpy as np
import pytest

from sparsebtf.codec import encode
from sparsebtf.errors import BTFInputError
from sparsebtf.learning.highlights import Highlights, correction, lobe_corrections, node_keys
from sparsebtf.learning.lobes import lobe_values
from sparsebtf.points.grid import PatchGrid
from sparsebtf.runtime import RuntimeBTF, angular_weights, grouping
from sparsebtf.runtime.decoder import query_texels
from sparsebtf.runtime.dense import DecodedBTF
from sparsebtf.runtime.kernels import HAVE_NUMBA

from .conftest import smooth_btf, tiny_model

SCHEMES = ("nearest", "linear", "barycentric", "gaussian")
BACKENDS = ("numpy", "numba") if HAVE_NUMBA else ("numpy",)
#: float32 rounding of values up to a few units (the corrections are summed in float64)
TOL = {"rtol": 1e-5, "atol": 2e-6}


@pytest.fixture(scope="module")
def coded():
    """A tiny model's codes of an 8×8 BTF (4 points of 4×4 texels, 13 × 13 directions)."""
    return encode(smooth_btf(9), tiny_model(max_iter=2), tau=(100, 20, 20), eps=0.0,
                  progress=False)  # fmt: skip


def random_lobes(coded, rng) -> np.ndarray:
    """(P, p², 8) float16 lobes: rotation vectors of norm < 1, ln α in [ln 0.05, ln 0.4],
    amplitudes in [0, 2]."""
    shape = (coded.n_points, coded.patch**2)
    axis = rng.normal(size=(*shape, 3))
    axis /= np.linalg.norm(axis, axis=-1, keepdims=True)
    omega = axis * rng.uniform(0, 0.99, (*shape, 1))
    ln_alpha = rng.uniform(np.log(0.05), np.log(0.4), (*shape, 2))
    amp = rng.uniform(0, 2, (*shape, 3))
    return np.concatenate([omega, ln_alpha, amp], axis=-1).astype(np.float16)


def random_store(coded, seed: int = 0, share: float = 0.4, scale: float = 0.6,
                 lobes: bool = False) -> Highlights:  # fmt: skip
    """Entries at a random ``share`` of each point's nodes (none at share 0), N(0, scale²)
    corrections (many negative enough to be clamped); with ``lobes`` a random lobe per texel
    (:func:`random_lobes`)."""
    rng = np.random.default_rng(seed)
    p, nl, nv = coded.patch, len(coded.lights), len(coded.views)
    per_point = p * p * nl * nv
    points, keys = [], []
    for pt in range(coded.n_points):
        k = rng.choice(per_point, int(share * per_point), replace=False)
        points.append(np.full(k.size, pt))
        keys.append(k)
    points, keys = np.concatenate(points), np.concatenate(keys)
    h = Highlights.from_nodes(points, keys, rng.normal(0, scale, (keys.size, 3)),
                              coded.n_points)  # fmt: skip
    return replace(h, lobes=random_lobes(coded, rng)) if lobes else h


@pytest.fixture(scope="module")
def lit(coded):
    return replace(coded, highlights=random_store(coded))


def _dirs(rng, n):
    v = rng.normal(size=(n, 3))
    v[:, 2] = np.abs(v[:, 2]) + 0.08
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def _queries(coded, n, seed, kind):
    rng = np.random.default_rng(seed)
    wi, wo = _dirs(rng, n), _dirs(rng, n)
    tex = rng.integers(0, coded.height, (n, 2))
    if kind == "texel":
        return wi, wo, {"texel": tex}
    # away from texel borders, wrapping beyond [0, 1)
    uv = (tex[:, ::-1] + rng.uniform(0.2, 0.8, (n, 2))) / coded.height + rng.integers(-1, 2,
                                                                                      (n, 1))
    return wi, wo, {"uv": uv}


def _reference(coded, h, base, wi, wo, where, scheme):
    """max(decode without the store + correction + lobe, 0), with the reference's weights;
    the correction and the lobe term (0 without lobes) returned too."""
    row, col = query_texels(where.get("uv"), where.get("texel"), coded.height, coded.width)
    pts, i1, i2 = PatchGrid(coded.height, coded.width, coded.patch).locate(row, col)
    li, lw = angular_weights(coded.lights, wi, scheme)
    vi, vw = angular_weights(coded.views, wo, scheme)
    c = correction(h, pts, i1, i2, li, lw, vi, vw, coded.patch, len(coded.lights),
                   len(coded.views))  # fmt: skip
    lobe = lobe_corrections(h, pts, np.asarray(i1) * coded.patch + np.asarray(i2), wi, wo)
    return np.maximum(base.astype(np.float64) + c + lobe, 0.0), c, lobe


@pytest.mark.parametrize("scheme", SCHEMES)
@pytest.mark.parametrize("kind", ["uv", "texel"])
@pytest.mark.parametrize("n", [20, 2000])  # 2000 ≥ 2·GROUP: grouped, texel groups too
@pytest.mark.parametrize("per_query_tau", [False, True])
def test_runtime_paths_equal_decode_plus_correction(coded, lit, scheme, kind, n, per_query_tau):
    assert 2000 >= 2 * grouping.GROUP and 20 < 2 * grouping.GROUP
    wi, wo, where = _queries(coded, n, 1 + n, kind)
    tau = None
    if per_query_tau:
        tau = np.random.default_rng(n).uniform(0, 20, n)  # every channel's loaded τ ≥ 20
    plain, with_h = RuntimeBTF(coded), RuntimeBTF(lit)
    for be in BACKENDS:
        base = plain.evaluate(wi, wo, interpolation=scheme, tau=tau, backend=be, **where)
        ref, c, _ = _reference(coded, lit.highlights, base, wi, wo, where, scheme)
        got = with_h.evaluate(wi, wo, interpolation=scheme, tau=tau, backend=be, **where)
        assert got.dtype == np.float32
        np.testing.assert_allclose(got, ref, **TOL, err_msg=be)
        # the test sees corrections at work: large ones, and values clamped to 0
        assert (np.abs(c) > 0.05).mean() > 0.2
        assert ((ref == 0) & (base > 0)).any()
    # the log-domain path (a NumPy-structured path with numba kernels) and log-YUV output
    got = with_h.evaluate(wi, wo, interpolation=scheme, domain="log", tau=tau, **where)
    base = plain.evaluate(wi, wo, interpolation=scheme, domain="log", tau=tau, **where)
    np.testing.assert_allclose(got, _reference(coded, lit.highlights, base, wi, wo, where,
                                               scheme)[0], **TOL)  # fmt: skip
    yuv = with_h.evaluate(wi, wo, interpolation=scheme, output="log_yuv", **where)
    np.testing.assert_array_equal(yuv, plain.evaluate(wi, wo, interpolation=scheme,
                                                      output="log_yuv", **where))


@pytest.mark.parametrize("backend", BACKENDS)
def test_at_a_sampled_node_nearest_adds_the_stored_correction(coded, lit, backend):
    """wi, wo exactly a light and a view: one-hot weights, value = decode + c of that node
    (c = 0 at a node without an entry), clamped at 0."""
    h = lit.highlights
    rng = np.random.default_rng(3)
    n = 300
    tex = rng.integers(0, coded.height, (n, 2))
    light, view = rng.integers(0, len(coded.lights), n), rng.integers(0, len(coded.views), n)
    wi, wo = coded.lights.xyz[light], coded.views.xyz[view]
    pts, i1, i2 = PatchGrid(coded.height, coded.width, coded.patch).locate(tex[:, 0], tex[:, 1])
    keys = node_keys(i1, i2, light, view, coded.patch, len(coded.lights), len(coded.views))
    c = np.zeros((n, 3))
    stored = np.zeros(n, dtype=bool)
    for q in range(n):
        lo, hi = h.offsets[pts[q]], h.offsets[pts[q] + 1]
        j = lo + np.searchsorted(h.keys[lo:hi], keys[q])
        if j < hi and h.keys[j] == keys[q]:
            c[q], stored[q] = h.rgb[j].astype(np.float64), True
    assert 0.2 < stored.mean() < 0.7
    base = RuntimeBTF(coded).evaluate(wi, wo, texel=tex, interpolation="nearest",
                                      backend=backend)  # fmt: skip
    got = RuntimeBTF(lit).evaluate(wi, wo, texel=tex, interpolation="nearest", backend=backend)
    want = np.maximum(base.astype(np.float64) + c, 0.0).astype(np.float32)
    if backend == "numba":  # float32 decode + c, rounded once: exact
        np.testing.assert_array_equal(got, want)
    else:  # the float64 decode + c, rounded once (the float32 decode is rounded too)
        np.testing.assert_allclose(got, want, rtol=1.2e-7, atol=2.5e-7)  # decode ≤ 2: ulp
    np.testing.assert_array_equal(got[~stored], np.maximum(base[~stored], 0))


@pytest.mark.parametrize("backend", BACKENDS)
def test_no_store_or_an_empty_one_changes_nothing(coded, backend):
    wi, wo, where = _queries(coded, 500, 7, "uv")
    plain = RuntimeBTF(coded).evaluate(wi, wo, backend=backend, **where)
    for h in (None, Highlights.empty(coded.n_points)):
        rt = RuntimeBTF(replace(coded, highlights=h))
        assert rt._highlights is None
        got = rt.evaluate(wi, wo, backend=backend, **where)
        np.testing.assert_array_equal(got, plain)


def test_a_store_that_does_not_fit_is_refused(coded):
    p, nl, nv = coded.patch, len(coded.lights), len(coded.views)
    bad = Highlights.from_nodes([0], [p * p * nl * nv], [[1.0, 1.0, 1.0]], coded.n_points)
    with pytest.raises(BTFInputError, match="highlights: key"):
        RuntimeBTF(replace(coded, highlights=bad))


# -- highlight lobes: the runtime ---------------------------------------------------------------
@pytest.fixture(scope="module")
def lobed(coded):
    """The material with a random lobe per texel and entries at 40 % of the nodes."""
    return replace(coded, highlights=random_store(coded, seed=11, lobes=True))


@pytest.fixture(scope="module")
def lobes_only(coded):
    """The material with random lobes and no entry."""
    return replace(coded, highlights=random_store(coded, seed=12, share=0.0, lobes=True))


@pytest.mark.parametrize("scheme", SCHEMES)
@pytest.mark.parametrize("n", [20, 2000])  # small and grouped batches
@pytest.mark.parametrize("entries", [True, False])
@pytest.mark.parametrize("per_query_tau", [False, True])
def test_runtime_adds_the_lobes_at_the_query_directions(coded, lobed, lobes_only, scheme, n,
                                                        entries, per_query_tau):  # fmt: skip
    """numba = NumPy = decode + correction + lobe_corrections at (wi, wo), clamped; the lobes
    come at any τ' and with no entry too."""
    lit = lobed if entries else lobes_only
    h = lit.highlights
    assert (h.n_entries > 0) == entries and h.lobes is not None
    wi, wo, where = _queries(coded, n, 100 + n, "uv")
    # lengths other than 1: the lobe is evaluated at the normalised directions
    scale = np.random.default_rng(n).uniform(0.5, 2.0, (n, 1))
    wi, wo = wi * scale, wo / scale
    tau = np.random.default_rng(n + 1).uniform(0, 20, n) if per_query_tau else None
    plain, with_h = RuntimeBTF(coded), RuntimeBTF(lit)
    for be in BACKENDS:
        base = plain.evaluate(wi, wo, interpolation=scheme, tau=tau, backend=be, **where)
        ref, _, lobe = _reference(coded, h, base, wi, wo, where, scheme)
        got = with_h.evaluate(wi, wo, interpolation=scheme, tau=tau, backend=be, **where)
        np.testing.assert_allclose(got, ref, **TOL, err_msg=be)
        assert (lobe.max(axis=1) > 0.1).mean() > 0.1  # the lobes show
    got = with_h.evaluate(wi, wo, interpolation=scheme, domain="log", tau=tau, **where)
    base = plain.evaluate(wi, wo, interpolation=scheme, domain="log", tau=tau, **where)
    np.testing.assert_allclose(got, _reference(coded, h, base, wi, wo, where, scheme)[0], **TOL)


def test_lobes_only_store_makes_a_table(coded, lobes_only):
    rt = RuntimeBTF(lobes_only)
    t = rt._highlights
    assert t is not None and t.lobes.shape == (coded.n_points, coded.patch**2, 8)
    assert t.lobes.dtype == np.float32 and t.keys.size == 0
    no_lobes = RuntimeBTF(replace(coded, highlights=random_store(coded)))._highlights
    assert no_lobes.lobes.shape == (0, 0, 8)


@pytest.mark.parametrize("backend", BACKENDS)
def test_runtime_with_lobes_at_sampled_directions_equals_dense(coded, lobed, lobes_only,
                                                               backend):  # fmt: skip
    """At a light and a view of the material, nearest: the runtime = DecodedBTF (which adds
    the lobes at the node directions)."""
    rng = np.random.default_rng(4)
    n = 400
    tex = rng.integers(0, coded.height, (n, 2))
    light, view = rng.integers(0, len(coded.lights), n), rng.integers(0, len(coded.views), n)
    for lit in (lobed, lobes_only):
        dense = np.asarray(DecodedBTF(lit).to_array())
        got = RuntimeBTF(lit).evaluate(coded.lights.xyz[light], coded.views.xyz[view],
                                       texel=tex, interpolation="nearest", backend=backend)
        want = dense[tex[:, 0], tex[:, 1], light, view]
        np.testing.assert_allclose(got, want, rtol=2e-5, atol=2e-5)
        plain = np.asarray(DecodedBTF(coded).to_array())[tex[:, 0], tex[:, 1], light, view]
        assert np.abs(want - plain).max() > 0.1  # the lobes show


def test_arrays_carry_the_lobes_by_texel_row(coded, lobed, lobes_only):
    """``highlight_lobes`` (P·p², 8) float32, row point·p² + i1·p + i2; a store of lobes
    only still gives valid (empty) offsets, keys and rgb."""
    p, pp = coded.patch, coded.patch**2
    rng = np.random.default_rng(6)
    for lit in (lobed, lobes_only):
        a = RuntimeBTF(lit).arrays(neighbours=False)
        h = lit.highlights
        lb = a["highlight_lobes"]
        assert lb.shape == (coded.n_points * pp, 8) and lb.dtype == np.float32
        n = 200
        pt = rng.integers(0, coded.n_points, n)
        i1, i2 = rng.integers(0, p, n), rng.integers(0, p, n)
        wi, wo = _dirs(rng, n), _dirs(rng, n)
        got = lobe_values(lb[pt * pp + i1 * p + i2], wi, wo)
        want = lobe_values(h.lobes[pt, i1 * p + i2].astype(np.float64), wi, wo)
        np.testing.assert_array_equal(got, want)
        assert np.abs(want).max() > 0.1
        assert a["highlight_offsets"].shape == (coded.n_points + 1,)
        assert a["highlight_offsets"].dtype == np.uint32
        assert a["highlight_keys"].shape == (h.n_entries,)
        assert a["highlight_keys"].dtype == np.uint32
        assert a["highlight_rgb"].shape == (h.n_entries, 3)
        assert a["highlight_rgb"].dtype == np.float32
    assert "highlight_lobes" not in RuntimeBTF(replace(coded, highlights=random_store(coded))
                                               ).arrays(neighbours=False)  # fmt: skip


# -- the Mitsuba plugin -------------------------------------------------------------------------
def _mitsuba():
    if importlib.util.find_spec("mitsuba") is None or importlib.util.find_spec("drjit") is None:
        pytest.skip("mitsuba/drjit not installed (pip install mitsuba drjit)")
    from sparsebtf import llvm

    status = llvm.configure()
    if not status.ok:
        pytest.skip(f"Dr.Jit LLVM backend unusable here: {status.message()}")
    import drjit as dr
    import mitsuba as mi

    import sparsebtf.mitsuba as sbm

    sbm.setup("llvm")
    return mi, dr, sbm


@pytest.mark.parametrize("scheme", SCHEMES)
def test_mitsuba_plugin_adds_the_corrections(coded, lit, scheme):
    """eval = RuntimeBTF.evaluate(light = wo, view = si.wi) on a material with highlights,
    through the Dr.Jit kernel (backend drjit) and the host runtime (backend numba)."""
    mi, _, sbm = _mitsuba()
    from sparsebtf.rendering.mitsuba.materials import BSDF_PER_BTF_VALUE

    from .test_mitsuba import _si  # the surface interaction of the plugin's tests

    rt = RuntimeBTF(lit)
    key = sbm.add_material(rt, "test-highlights")
    rng = np.random.default_rng(5)
    n = 400
    wi, wo = _dirs(rng, n).astype(np.float32), _dirs(rng, n).astype(np.float32)
    tex = rng.integers(-8, 16, (n, 2))
    uv = ((tex + rng.uniform(0.2, 0.8, (n, 2))) / 8).astype(np.float32)
    ref = rt.evaluate(wo, wi, uv=uv, interpolation=scheme)
    plain = RuntimeBTF(coded).evaluate(wo, wi, uv=uv, interpolation=scheme)
    assert np.abs(ref - np.maximum(plain, 0)).max() > 0.1  # the corrections show
    backends = ("drjit", "numba") if HAVE_NUMBA else ("drjit",)
    for be in backends:
        bsdf = mi.load_dict({"type": "sparsebtf", "key": key, "interpolation": scheme,
                             "backend": be})  # fmt: skip
        out = np.array(bsdf.eval(mi.BSDFContext(), _si(wi, uv), mi.Vector3f(wo.T)))
        got = (out if out.shape[-1] == 3 else out.T) / np.float32(BSDF_PER_BTF_VALUE)
        np.testing.assert_allclose(got, ref, rtol=2e-5, atol=2e-6, err_msg=be)


def test_mitsuba_renders_with_highlights_agree_in_both_modes(coded, lit):
    """A symbolic render (the Dr.Jit kernel inside Mitsuba's recorded calls) equals an
    evaluated one (the host runtime), and both differ from the material without the store."""
    _, _, sbm = _mitsuba()
    from sparsebtf.rendering.render import render_material

    opts = {"scene": "sphere", "size": (12, 12), "spp": 1, "seed": 3, "lod": "off"}
    plugin = {"type": "sparsebtf", "key": sbm.add_material(RuntimeBTF(lit), "test-hl-render")}
    sym = render_material(plugin, mode="symbolic", **opts)
    ev = render_material(plugin, mode="evaluated", **opts)
    assert sym["mode"] == "symbolic" and ev["mode"] == "evaluated"
    np.testing.assert_allclose(ev.image, sym.image, rtol=1e-4, atol=1e-6)
    plain = {"type": "sparsebtf", "key": sbm.add_material(RuntimeBTF(coded), "test-hl-plain")}
    base = render_material(plain, mode="symbolic", **opts)
    assert np.abs(base.image - sym.image).max() > 1e-2


@pytest.mark.parametrize("scheme", SCHEMES)
def test_mitsuba_plugin_adds_the_lobes(coded, lobed, lobes_only, scheme):
    """eval = RuntimeBTF.evaluate(light = wo, view = si.wi) on a material with lobes (with and
    without entries), through the Dr.Jit kernel and the host runtime, importance transport
    (roles swapped) too."""
    mi, _, sbm = _mitsuba()
    from sparsebtf.rendering.mitsuba.materials import BSDF_PER_BTF_VALUE

    from .test_mitsuba import _si

    rng = np.random.default_rng(8)
    n = 400
    wi, wo = _dirs(rng, n).astype(np.float32), _dirs(rng, n).astype(np.float32)
    tex = rng.integers(-8, 16, (n, 2))
    uv = ((tex + rng.uniform(0.2, 0.8, (n, 2))) / 8).astype(np.float32)
    plain = RuntimeBTF(coded).evaluate(wo, wi, uv=uv, interpolation=scheme)
    backends = ("drjit", "numba") if HAVE_NUMBA else ("drjit",)
    for name, lit in (("lobed", lobed), ("lobes-only", lobes_only)):
        rt = RuntimeBTF(lit)
        key = sbm.add_material(rt, f"test-lobes-{name}")
        for mode in ("radiance", "importance"):
            light, view = (wo, wi) if mode == "radiance" else (wi, wo)
            ref = rt.evaluate(light, view, uv=uv, interpolation=scheme)
            if mode == "radiance":
                assert np.abs(ref - np.maximum(plain, 0)).max() > 0.1
            ctx = mi.BSDFContext(mi.TransportMode.Importance if mode == "importance"
                                 else mi.TransportMode.Radiance)  # fmt: skip
            for be in backends:
                bsdf = mi.load_dict({"type": "sparsebtf", "key": key, "interpolation": scheme,
                                     "backend": be})  # fmt: skip
                out = np.array(bsdf.eval(ctx, _si(wi, uv), mi.Vector3f(wo.T)))
                got = (out if out.shape[-1] == 3 else out.T) / np.float32(BSDF_PER_BTF_VALUE)
                np.testing.assert_allclose(got, ref, rtol=1e-4, atol=2e-6,
                                           err_msg=f"{name} {mode} {be}")  # fmt: skip


def test_mitsuba_renders_with_lobes_agree_in_both_modes(coded, lobes_only):
    """A symbolic render (the Dr.Jit kernel's lobes) equals an evaluated one (the host
    runtime's), and both differ from the material without the lobes."""
    _, _, sbm = _mitsuba()
    from sparsebtf.rendering.render import render_material

    opts = {"scene": "sphere", "size": (12, 12), "spp": 1, "seed": 3, "lod": "off"}
    plugin = {"type": "sparsebtf", "key": sbm.add_material(RuntimeBTF(lobes_only), "test-lb-r")}
    sym = render_material(plugin, mode="symbolic", **opts)
    ev = render_material(plugin, mode="evaluated", **opts)
    np.testing.assert_allclose(ev.image, sym.image, rtol=1e-4, atol=1e-6)
    plain = {"type": "sparsebtf", "key": sbm.add_material(RuntimeBTF(coded), "test-lb-plain")}
    base = render_material(plain, mode="symbolic", **opts)
    assert np.abs(base.image - sym.image).max() > 1e-2

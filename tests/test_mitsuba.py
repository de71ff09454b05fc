"""Mitsuba 3 plugins ``sparsebtf`` / ``sparsebtf_dense``: values, conventions, sampling, renders.

Skips (with the reason) when Mitsuba is not installed or when no libLLVM usable by Dr.Jit's LLVM
backend is found (the probe runs in a subprocess: LLVM 15/16 would abort the process).
"""

from __future__ import annotations

import importlib.util
import os

import numpy as np
import pytest

from sparsebtf import llvm
from sparsebtf.codec import encode
from sparsebtf.errors import BTFInputError
from sparsebtf.runtime import coded_btf_view

from .conftest import smooth_btf, tight_bound, tiny_model

if importlib.util.find_spec("mitsuba") is None or importlib.util.find_spec("drjit") is None:
    pytest.skip("mitsuba/drjit not installed (pip install mitsuba drjit)", allow_module_level=True)
_status = llvm.configure()
if not _status.ok:
    pytest.skip(f"Dr.Jit LLVM backend unusable here: {_status.message()}", allow_module_level=True)

import drjit as dr  # noqa: E402
import mitsuba as mi  # noqa: E402

import sparsebtf.mitsuba as sbm  # noqa: E402
from sparsebtf.rendering.mitsuba import preload  # noqa: E402
from sparsebtf.rendering.mitsuba.materials import BSDF_PER_BTF_VALUE  # noqa: E402
from sparsebtf.rendering.render import compare_renders, render_material  # noqa: E402
from sparsebtf.runtime import RuntimeBTF, angular_weights  # noqa: E402

SCHEMES = ("nearest", "linear", "barycentric", "gaussian")
#: The plugin's lookups: its Dr.Jit kernel, and the host runtime (numba) in evaluated calls.
BACKENDS = ("drjit", "numba")


@pytest.fixture(autouse=True)
def _llvm_variant():
    sbm.setup("llvm")
    yield


@pytest.fixture(scope="module")
def material():
    """A tiny trained model, a BTF it never saw, its codes at two levels, as plugin keys."""
    model = tiny_model(max_iter=3)
    btf = smooth_btf(9)
    lossy = encode(btf, model, tau=(100, 20, 20), eps=0.0, progress=False)
    lossless = encode(btf, model, tau=4 * 4 * 13 * 13, eps=0.0, progress=False)
    rt = RuntimeBTF(lossy)
    tight = RuntimeBTF(tight_bound(lossy))
    return {
        "btf": btf,
        "rt": rt,
        "rt_tight": tight,
        "key_tight": sbm.add_material(tight, "test-tight"),
        "key": sbm.add_material(rt, "test-lossy"),
        "key_lossless": sbm.add_material(lossless, "test-lossless"),
        "key_dense": sbm.add_material(btf, "test-dense"),
        "key_other": sbm.add_material(smooth_btf(5), "test-other"),
    }


def _dirs(rng, n, lo=0.08):
    v = rng.normal(size=(n, 3))
    v[:, 2] = np.abs(v[:, 2]) + lo
    return (v / np.linalg.norm(v, axis=1, keepdims=True)).astype(np.float32)


def _si(wi, uv, flip=False):
    n = wi.shape[0]
    si = dr.zeros(mi.SurfaceInteraction3f, n)
    si.wi = mi.Vector3f(wi.T)
    si.uv = mi.Point2f(uv.T)
    si.sh_frame = mi.Frame3f(mi.Vector3f(1, 0, 0), mi.Vector3f(0, 1, 0), mi.Vector3f(0, 0, 1))
    si.dp_du = mi.Vector3f(1, 0, 0)
    si.dp_dv = mi.Vector3f(0, -1 if flip else 1, 0)
    return si


def _eval(bsdf, si, wo, ctx=None):
    """The BTF value a plugin's eval stands for: eval / BSDF_PER_BTF_VALUE (eval is f·cos θ,
    a BTF value π·f·cos θ_light; ``test_a_lambertian_btf_renders_as_mitsubas_diffuse``)."""
    out = np.array(bsdf.eval(ctx or mi.BSDFContext(), si, mi.Vector3f(wo.T)))
    return (out if out.shape[-1] == 3 else out.T) / np.float32(BSDF_PER_BTF_VALUE)


def _queries(seed=0, n=400):
    rng = np.random.default_rng(seed)
    # uv away from texel borders (float32 vs float64 floor), wrapping beyond [0, 1)
    tex = rng.integers(-8, 16, (n, 2))
    uv = ((tex + rng.uniform(0.2, 0.8, (n, 2))) / 8).astype(np.float32)
    return _dirs(rng, n), _dirs(rng, n), uv


def test_llvm_probe_finds_a_working_library_and_survives_bad_ones(tmp_path):
    assert _status.ok and int(_status.version.split(".")[0]) >= llvm.MIN_MAJOR
    assert _status.message() == f"Dr.Jit LLVM backend: {_status.path} (LLVM {_status.version})"
    assert os.environ["DRJIT_LIBLLVM_PATH"] == _status.path
    ok, why = llvm.probe_libllvm(str(tmp_path / "libLLVM.so.19"))
    assert not ok and why
    # LLVM 15/16 abort the process that loads them; the probe's subprocess takes the hit.
    bad = [p for p in ("/usr/lib/x86_64-linux-gnu/libLLVM-15.so.1",) if os.path.exists(p)]
    for p in bad:
        ok, why = llvm.probe_libllvm(p)
        assert not ok, why
    assert llvm.choose_variant("auto")[0] == "llvm_ad_rgb"
    old = "/usr/lib/x86_64-linux-gnu/libLLVM-14.so.1"
    if os.path.exists(old):  # one message in Dr.Jit's and our terms, not "(-1, -1, -1)"
        ok, why = llvm.probe_libllvm(old, timeout=900)  # 120 s ran out on a loaded machine
        assert not ok and why.startswith("LLVM 14 is too old: sparsebtf needs LLVM >= 17")


def test_libllvm_from_a_pip_wheel_is_found_and_works():
    """Rendering without root: a libLLVM that pip installed (``karellen-llvm-core``, the
    ``render`` extra) lies under the environment's lib/, is a candidate, and runs Dr.Jit."""
    import sys

    wheel = [p for p in llvm.candidate_libraries()
             if p.startswith(os.path.realpath(os.path.join(sys.prefix, "lib")))]  # fmt: skip
    if not wheel:
        pytest.skip("no pip-installed libLLVM here (pip install 'sparsebtf[render]')")
    ok, version = llvm.probe_libllvm(wheel[0])
    assert ok and int(version.split(".")[0]) >= 23, version


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("domain", ["standardized", "log"])
@pytest.mark.parametrize("scheme", SCHEMES)
def test_eval_equals_runtime_decoder(material, scheme, domain, backend):
    """eval(si, wo) = RuntimeBTF.evaluate(light = wo, view = si.wi, uv) (float32 tolerance),
    through the Dr.Jit kernel and through the host runtime (a direct call is evaluated)."""
    wi, wo, uv = _queries(1)
    bsdf = mi.load_dict({"type": "sparsebtf", "key": material["key"], "interpolation": scheme,
                         "domain": domain, "backend": backend})  # fmt: skip
    got = _eval(bsdf, _si(wi, uv), wo)
    ref = material["rt"].evaluate(wo, wi, uv=uv, interpolation=scheme, domain=domain)
    np.testing.assert_allclose(got, np.maximum(ref, 0), rtol=2e-5, atol=2e-6)
    assert np.ptp(ref) > 0.1  # the queries see a varied material


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("domain", ["standardized", "log"])
def test_eval_clamps_to_the_bound_like_the_runtime_decoder(material, domain, backend):
    wi, wo, uv = _queries(2)
    bsdf = mi.load_dict({"type": "sparsebtf", "key": material["key_tight"], "domain": domain,
                         "backend": backend})  # fmt: skip
    got = _eval(bsdf, _si(wi, uv), wo)
    ref = material["rt_tight"].evaluate(wo, wi, uv=uv, domain=domain)
    np.testing.assert_allclose(got, np.maximum(ref, 0), rtol=2e-5, atol=2e-6)
    free = material["rt"].evaluate(wo, wi, uv=uv, domain=domain)
    assert (free > ref * (1 + 1e-3) + 1e-6).mean() > 0.1  # the clamp is at work


def test_eval_conventions(material):
    rt = material["rt"]
    wi, wo, uv = _queries(2, 64)
    plain = mi.load_dict({"type": "sparsebtf", "key": material["key"]})
    ref = rt.evaluate(wo, wi, uv=uv)
    # the light is Mitsuba's wo, the view is si.wi: swapping them changes the value ...
    swapped = rt.evaluate(wi, wo, uv=uv)
    assert np.abs(swapped - ref).max() > 1e-3
    # ... and in importance transport (light tracing) the roles swap
    ctx = mi.BSDFContext(mi.TransportMode.Importance)
    np.testing.assert_allclose(_eval(plain, _si(wi, uv), wo, ctx), swapped, rtol=2e-5, atol=2e-6)
    # uv tiling
    tiled = mi.load_dict({"type": "sparsebtf", "key": material["key"], "uv_scale": 3.0})
    np.testing.assert_allclose(
        _eval(tiled, _si(wi, uv / 3), wo), ref, rtol=2e-5, atol=2e-6
    )
    # left-handed parametrisation (t = -dp/dv): both directions' local y is negated
    mirror = np.array([1, -1, 1], np.float32)
    np.testing.assert_allclose(
        _eval(plain, _si(wi, uv, flip=True), wo),
        rt.evaluate(wo * mirror, wi * mirror, uv=uv),
        rtol=2e-5,
        atol=2e-6,
    )
    # below the horizon: zero one-sided; two-sided mirrors back-face hits to the front
    down = np.array([1, 1, -1], np.float32)
    assert np.all(_eval(plain, _si(wi * down, uv), wo * down) == 0)
    assert np.all(_eval(plain, _si(wi, uv), wo * down) == 0)
    two = mi.load_dict({"type": "sparsebtf", "key": material["key"], "two_sided": True})
    np.testing.assert_allclose(_eval(two, _si(wi * down, uv), wo * down), ref, rtol=2e-5,
                               atol=2e-6)  # fmt: skip
    assert np.all(_eval(two, _si(wi * down, uv), wo) == 0)  # opposite sides: no transmission


def _np(x):
    """A Dr.Jit vector/colour as an (n, d) NumPy array."""
    a = np.array(x)
    return a.T if a.ndim == 2 and a.shape[0] in (2, 3) and a.shape[1] not in (2, 3) else a


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("sampling", ["cosine", "btf"])
@pytest.mark.parametrize("mode", ["radiance", "importance"])
def test_pdf_and_sample_weight_are_consistent(material, sampling, mode, backend):
    """bs.pdf is pdf(bs.wo) bit for bit, the weight is eval/pdf, on both sides (two-sided)."""
    wi, _, uv = _queries(3, 256)
    rng = np.random.default_rng(4)
    ctx = mi.BSDFContext(mi.TransportMode.Importance if mode == "importance" else
                         mi.TransportMode.Radiance)  # fmt: skip
    bsdf = mi.load_dict({"type": "sparsebtf", "key": material["key"], "two_sided": True,
                         "sampling": sampling, "backend": backend})  # fmt: skip
    for side in (1, -1):
        w_in = wi * np.array([1, 1, side], np.float32)
        si = _si(w_in, uv)
        u1 = rng.uniform(size=256).astype(np.float32)
        u2 = rng.uniform(size=(256, 2)).astype(np.float32)
        bs, weight = bsdf.sample(ctx, si, mi.Float(u1), mi.Point2f(u2.T))
        wo = _np(bs.wo)
        assert np.all(np.sign(wo[:, 2]) == side)
        pdf = np.array(bsdf.pdf(ctx, si, bs.wo))
        np.testing.assert_array_equal(np.array(bs.pdf), pdf)
        value, pdf2 = bsdf.eval_pdf(ctx, si, bs.wo)
        np.testing.assert_array_equal(np.array(pdf2), pdf)
        if sampling == "cosine":
            np.testing.assert_allclose(pdf, np.abs(wo[:, 2]) / np.pi, rtol=1e-5)
        val = _eval(bsdf, si, wo, ctx) * np.float32(BSDF_PER_BTF_VALUE)  # eval's own value
        np.testing.assert_allclose(_np(value), val, rtol=1e-6, atol=1e-7)
        np.testing.assert_allclose(_np(weight), val / pdf[:, None], rtol=1e-4)


def _glossy_btf(seed=11, size=8):
    """A small BTF with a mirror lobe (exp(-(1 - r·v)/0.08), r the mirrored light) over a
    dim diffuse base, times cos θ_light: the glossy counterpart of ``smooth_btf``."""
    from sparsebtf.data.btf import ArrayBTF
    from sparsebtf.data.directions import tiny

    rng = np.random.default_rng(seed)
    d = tiny(13)
    x = d.xyz
    r = x * np.array([-1, -1, 1])
    lobe = np.exp(-(1 - r @ x.T) / 0.08)  # (L, V)
    ang = x[:, 2:3] * (0.05 + 2.0 * lobe)
    base = rng.uniform(0.3, 1.0, (size, size, 1, 1, 3))
    data = base * ang[None, None, :, :, None]
    return ArrayBTF(data.astype(np.float32), d, d, name="glossy")


@pytest.fixture(scope="module")
def glossy(material):
    """The glossy BTF coded with the test model at the lossy τ = (100, 20, 20) (the lobe stays:
    max/mean of its angular response ≈ 6.5, 1.3 for the smooth material)."""
    model = material["rt"].coded.require_model()
    coded = encode(_glossy_btf(), model, tau=(100, 20, 20), eps=0.0, progress=False)
    return sbm.add_material(coded, "test-glossy")


def _chi2(d, wi, ctx=None, pdf=None):
    """Mitsuba's chi² test of a plugin's sample() against its pdf() (or ``pdf``) at ``wi``.

    ires = 16 integration points per bin side: the BTF density is piecewise constant over its
    cells, and the default 4-point trapezoid rule misses the integral of such a density by
    0.3 % (PDF sum 1.003), enough to reject a correct sampler at normal incidence.
    """
    from mitsuba.chi2 import BSDFAdapter, ChiSquareTest, SphericalDomain

    w = np.array(wi) / np.linalg.norm(wi)
    sample, own_pdf = BSDFAdapter(d["type"], d, wi=[float(x) for x in w], ctx=ctx)
    return ChiSquareTest(SphericalDomain(), sample, pdf or own_pdf, sample_dim=3,
                         sample_count=200_000, res=41, ires=16, seed=3)  # fmt: skip


INCIDENCES = [[0.0, 0.0, 1.0], [0.6, -0.3, 0.74], [0.9, 0.2, 0.38], [0.5, 0.4, -0.77]]


@pytest.mark.parametrize("wi", INCIDENCES)
@pytest.mark.parametrize("which", ["diffuse", "glossy"])
def test_btf_sampling_passes_chi2(material, glossy, which, wi):
    key = glossy if which == "glossy" else material["key"]
    test = _chi2({"type": "sparsebtf", "key": key, "two_sided": True}, wi)
    assert test.run(), test.messages


@pytest.mark.parametrize(
    "extra",
    [{"sampling": "cosine"}, {"sampling_tables": "patch"}, {"interpolation": "barycentric"},
     {"interpolation": "nearest", "sampling_grid": 7, "sampling_mix": 0.5}],
)  # fmt: skip
def test_sampling_variants_pass_chi2(glossy, extra):
    d = {"type": "sparsebtf", "key": glossy, "two_sided": True, **extra}
    test = _chi2(d, [0.6, -0.3, 0.74])
    assert test.run(), test.messages


@pytest.mark.parametrize("wi", [[0.0, 0.0, 1.0], [0.9, 0.2, 0.38]])
def test_btf_sampling_passes_chi2_in_importance_transport(glossy, wi):
    ctx = mi.BSDFContext(mi.TransportMode.Importance)
    test = _chi2({"type": "sparsebtf", "key": glossy}, wi, ctx)
    assert test.run(), test.messages


def test_chi2_rejects_a_wrong_pdf(material, glossy, tmp_path, monkeypatch):
    """The chi2 check can fail: the cosine sampler against a cos² density, the BTF sampler
    against the cosine density it replaces."""
    monkeypatch.chdir(tmp_path)  # a failing ChiSquareTest writes chi2_data.py into the cwd

    def cos2_pdf(wo):
        c = dr.maximum(wo.z, 0.0)
        return c * c * 3.0 / (2.0 * dr.pi)

    def cos_pdf(wo):
        return dr.maximum(wo.z, 0.0) * dr.inv_pi

    d = {"type": "sparsebtf", "key": material["key"], "sampling": "cosine"}
    assert not _chi2(d, [0, 0, 1], pdf=cos2_pdf).run()
    assert not _chi2({"type": "sparsebtf", "key": glossy}, [0.6, -0.3, 0.74], pdf=cos_pdf).run()


def test_btf_sampler_matches_its_numpy_reference(glossy):
    """Dr.Jit sampler and pdf = :mod:`sampling`'s NumPy twins (same random numbers)."""
    from sparsebtf.rendering.mitsuba import materials, sampling
    from sparsebtf.runtime.response import angular_response

    n = 4000
    rng = np.random.default_rng(5)
    wi = _dirs(rng, n, lo=0.1)
    uv = rng.uniform(0, 1, (n, 2)).astype(np.float32)
    u1 = rng.uniform(size=n).astype(np.float32)
    u2 = rng.uniform(size=(n, 2)).astype(np.float32)
    d = {"type": "sparsebtf", "key": glossy, "interpolation": "barycentric",
         "sampling_tables": "patch", "sampling_grid": 12}  # fmt: skip
    bsdf = mi.load_dict(d)
    bs, _ = bsdf.sample(mi.BSDFContext(), _si(wi, uv), mi.Float(u1), mi.Point2f(u2.T))
    got = _np(bs.wo)
    rt = materials.load_runtime(("key", glossy))
    tables = sampling.build_tables(angular_response(rt, per_point=True), rt.coded.lights.xyz,
                                   rt.coded.views.xyz, "barycentric", grid=12)  # fmt: skip
    used = materials.coded_sampling(materials.coded_params(d), ("key", glossy), None, rt)
    np.testing.assert_array_equal(tables.cdf["radiance"], used.cdf["radiance"])
    idx, w = angular_weights(rt.coded.views, wi, "barycentric")
    row, col = np.floor(uv[:, 1] * 8).astype(int), np.floor(uv[:, 0] * 8).astype(int)
    pts = row // 4 + 2 * (col // 4)
    ref = sampling.sample(tables, "radiance", pts, idx, w, u1, u2)
    close = np.all(np.abs(got - ref) < 1e-4, axis=1)
    assert close.mean() > 0.995, close.mean()  # the rest: a uniform number on a CDF step
    ref_pdf = sampling.pdf(tables, "radiance", pts, idx, w, got.astype(np.float64))
    np.testing.assert_allclose(np.array(bs.pdf)[close], ref_pdf[close], rtol=2e-4)


def test_btf_sampling_lowers_the_weight_variance_of_a_glossy_material(material, glossy):
    """What the sampler is for: eval/pdf varies much less than with cosine sampling where the
    BTF has a lobe, and about as much on the smooth (diffuse-like) material."""
    n = 20000
    rng = np.random.default_rng(6)
    wi = np.tile(np.array([[0.6, -0.3, 0.74]], np.float32) / np.float32(1.0), (n, 1))
    wi /= np.linalg.norm(wi, axis=1, keepdims=True)
    uv = rng.uniform(0, 1, (n, 2)).astype(np.float32)
    u1 = mi.Float(rng.uniform(size=n).astype(np.float32))
    u2 = mi.Point2f(rng.uniform(size=(2, n)).astype(np.float32))
    ratio = {}
    for which, key in (("glossy", glossy), ("diffuse", material["key"])):
        var = {}
        for samp in ("cosine", "btf"):
            b = mi.load_dict({"type": "sparsebtf", "key": key, "sampling": samp})
            _, w = b.sample(mi.BSDFContext(), _si(wi, uv), u1, u2)
            lum = _np(w) @ np.array([0.2126, 0.7152, 0.0722])
            var[samp] = float(np.var(lum))
        ratio[which] = var["btf"] / var["cosine"]
    assert ratio["glossy"] < 0.5, ratio
    assert ratio["diffuse"] < 1.2, ratio


@pytest.mark.parametrize("scheme", SCHEMES)
def test_dense_reference_plugin(material, scheme):
    """Dense lookups: the log-domain blend of the table's neighbours; exact at measured bins."""
    btf = material["btf"]
    table = btf.to_array().astype(np.float64)
    wi, wo, uv = _queries(5, 200)
    bsdf = mi.load_dict({"type": "sparsebtf_dense", "key": material["key_dense"],
                         "interpolation": scheme})  # fmt: skip
    got = _eval(bsdf, _si(wi, uv), wo)
    li, lw = angular_weights(btf.lights, wo, scheme)
    vi, vw = angular_weights(btf.views, wi, scheme)
    row = np.floor((uv[:, 1] % 1) * btf.height).astype(int)
    col = np.floor((uv[:, 0] % 1) * btf.width).astype(int)
    logs = np.log(np.maximum(table, 0) + 1e-5)[row[:, None, None], col[:, None, None],
                                                li[:, :, None], vi[:, None, :]]  # fmt: skip
    ref = np.exp(np.einsum("na,nb,nabc->nc", lw, vw, logs)) - 1e-5
    np.testing.assert_allclose(got, ref, rtol=3e-5, atol=2e-6)
    if scheme == "nearest":  # at measured directions: the measured values themselves
        d = btf.lights.xyz.astype(np.float32)
        j = np.arange(200) % len(d)
        at = _eval(bsdf, _si(d[j[::-1]], uv), d[j])
        np.testing.assert_allclose(at, table[row, col, j, j[::-1]], rtol=3e-5, atol=2e-6)


def test_dense_reference_refuses_large_tables(material):
    from sparsebtf.rendering.mitsuba import dense_table

    with pytest.raises(BTFInputError, match=r"GiB.*limit.*crop"):
        dense_table(material["btf"], max_gib=1e-6)
    with pytest.raises(RuntimeError, match="GiB"):
        mi.load_dict({"type": "sparsebtf_dense", "key": material["key_dense"], "max_gib": 1e-6})


def test_bad_parameters_are_named(material):
    from sparsebtf.rendering.mitsuba import preload

    with pytest.raises(BTFInputError, match="interpolation"):
        preload({"type": "sparsebtf", "key": material["key"], "interpolation": "cubic"})
    with pytest.raises(BTFInputError, match="does not exist"):
        preload({"type": "sparsebtf", "filename": "/nonexistent/x.coded.h5"})
    with pytest.raises(BTFInputError, match="no material"):
        preload({"type": "sparsebtf", "key": "never-added"})


def test_file_loading_and_tau(material, tmp_path):
    """A coded file on disk with its model; tau loads a truncated level of detail."""
    from sparsebtf.storage import save_coded, save_model

    rt = material["rt"]
    mpath = save_model(rt.coded.require_model(), tmp_path / "model.h5")
    cpath = tmp_path / "m.coded.h5"
    save_coded(rt.coded, cpath)
    wi, wo, uv = _queries(6, 100)
    for tau in (None, "10,2,2"):
        d = {"type": "sparsebtf", "filename": str(cpath), "model": str(mpath)}
        if tau:
            d["tau"] = tau
        bsdf = mi.load_dict(d)
        ref = RuntimeBTF.from_file(cpath, mpath, tau=tau).evaluate(wo, wi, uv=uv)
        np.testing.assert_allclose(_eval(bsdf, _si(wi, uv), wo), ref, rtol=2e-5, atol=2e-6)
    assert "tau={'Y': 10, 'U': 2, 'V': 2}" in str(bsdf)


def test_meshes_have_a_right_handed_uv_frame():
    from sparsebtf.rendering.scenes import scene_dict

    for name in ("sphere", "cloth"):
        scene = mi.load_dict(scene_dict(mi, {"type": "diffuse"}, name, 32, 32))
        rng = np.random.default_rng(0)
        xy = rng.uniform(0, 1, (2048, 2)).astype(np.float32)
        ray, _ = scene.sensors()[0].sample_ray(0.0, 0.5, mi.Point2f(xy.T), mi.Point2f(0.5, 0.5))
        si = scene.ray_intersect(ray)
        hit = np.array(si.is_valid())
        assert hit.mean() > 0.5
        t_dv = np.array(dr.dot(si.sh_frame.t, dr.normalize(si.dp_dv)))[hit]
        s_du = np.array(dr.dot(si.sh_frame.s, dr.normalize(si.dp_du)))[hit]
        assert np.all(t_dv > 0.5), name  # t follows +dp/dv: the BTF's +v side
        assert np.all(s_du > 0.98), name  # s follows dp/du: azimuth 0 along +u


def test_render_close_to_reference(material):
    """Renders are finite; lossless codes render like the dense BTF; lossy codes within a bound.

    Bound (48x48, 8 spp, same sampler seed, sphere scene, linear interpolation): the relative
    MSE ‖coded − reference‖² / ‖reference‖² of the render follows the material's own coding
    error. Measured for τ = (100, 20, 20): render 0.009 (0.013 with cosine sampling), decoded
    BTF 0.014 (τ = (40, 8, 8), cosine: 0.042 and 0.030). Asserted: render < 0.03 and < 2x the
    BTF's. A different material under the same settings gives 0.45. The references sample with
    the coded material's tables (``sampling_key``), so both renders draw the same directions.
    """
    opts = {"scene": "sphere", "size": (48, 48), "spp": 8, "seed": 1}
    common = {"interpolation": "linear", "two_sided": True}

    def rel_mse(a, b):
        return float(np.mean((a - b) ** 2) / np.mean(b**2))

    def dense(key, like):
        return render_material({"type": "sparsebtf_dense", "key": key, "sampling_key": like,
                                **common}, **opts).image  # fmt: skip

    # the coding error alone: every lookup at the codes' full tau (lod off)
    lossless = render_material({"type": "sparsebtf", "key": material["key_lossless"],
                                "domain": "log", **common}, lod="off", **opts).image  # fmt: skip
    lossy = render_material({"type": "sparsebtf", "key": material["key"], **common}, lod="off",
                            **opts)  # fmt: skip
    ref = dense(material["key_dense"], material["key"])
    other = dense(material["key_other"], material["key"])
    for img in (ref, lossless, lossy.image, other):
        assert img.shape == (48, 48, 3) and np.all(np.isfinite(img)) and img.mean() > 0.05
    assert lossy["variant"] == "llvm_ad_rgb"
    assert rel_mse(lossless, dense(material["key_dense"], material["key_lossless"])) < 1e-6
    assert rel_mse(lossless, ref) > 1e-4  # other tables: the same seed draws other directions
    err = rel_mse(lossy.image, ref)
    btf = material["btf"]
    decoded = coded_btf_view(material["rt"].coded).to_array()
    btf_err = float(np.mean((decoded - btf.to_array()) ** 2) / np.mean(btf.to_array() ** 2))
    assert err < 0.03 and err < 2 * btf_err, (err, btf_err)
    assert rel_mse(other, ref) > 10 * err
    m = compare_renders(lossy.image, ref)
    # Quality is rel_mse's above; PSNR has the fixed peak 1.0, low for radiance far above 1.
    assert m["ssim"] > 0.95 and m["psnr"] == pytest.approx(-10 * np.log10(m["mse"]))


def test_scalar_variant_fallback(material):
    """scalar_rgb: the same values through RuntimeBTF.evaluate, the same BTF-driven samples
    and pdf as llvm (through the NumPy twins), and a tiny render."""
    wi, wo, uv = _queries(7, 5)
    rng = np.random.default_rng(8)
    u1, u2 = rng.uniform(size=5).astype(np.float32), rng.uniform(size=(5, 2)).astype(np.float32)
    d = {"type": "sparsebtf", "key": material["key"], "interpolation": "linear",
         "sampling_tables": "patch"}  # fmt: skip
    bs, weight = mi.load_dict(d).sample(mi.BSDFContext(), _si(wi, uv), mi.Float(u1),
                                        mi.Point2f(u2.T))  # fmt: skip
    jit_wo, jit_pdf, jit_w = _np(bs.wo), np.array(bs.pdf), _np(weight)
    try:
        mi.set_variant("scalar_rgb")
        sbm.register()
        b = mi.load_dict(d)
        ref = material["rt"].evaluate(wo, wi, uv=uv)
        for j in range(5):
            si = dr.zeros(mi.SurfaceInteraction3f)
            si.wi = mi.Vector3f(*wi[j])
            si.uv = mi.Point2f(*uv[j])
            np.testing.assert_allclose(np.array(b.eval(mi.BSDFContext(), si, mi.Vector3f(*wo[j]))),
                                       ref[j] * BSDF_PER_BTF_VALUE, rtol=1e-5)  # fmt: skip
            bs, w = b.sample(mi.BSDFContext(), si, float(u1[j]), mi.Point2f(*u2[j]))
            np.testing.assert_allclose(np.array(bs.wo), jit_wo[j], atol=1e-5)
            np.testing.assert_allclose(bs.pdf, jit_pdf[j], rtol=1e-4)
            assert bs.pdf == b.pdf(mi.BSDFContext(), si, bs.wo)
            np.testing.assert_allclose(np.array(w), jit_w[j], rtol=1e-3)
        res = render_material({"type": "sparsebtf", "key": material["key"]}, size=(8, 8), spp=2,
                              backend="scalar")  # fmt: skip
        assert res["variant"] == "scalar_rgb" and np.all(np.isfinite(res.image))
    finally:
        sbm.setup("llvm")


def test_adding_under_an_existing_key_replaces_the_material(material):
    wi, wo, uv = _queries(8, 50)
    d = {"type": "sparsebtf", "key": "test-replace"}
    sbm.add_material(material["rt"], "test-replace")
    first = _eval(mi.load_dict(d), _si(wi, uv), wo)
    low = material["rt"].with_tau("5,1,1")
    sbm.add_material(low, "test-replace")
    second = _eval(mi.load_dict(d), _si(wi, uv), wo)
    np.testing.assert_allclose(second, low.evaluate(wo, wi, uv=uv), rtol=2e-5, atol=2e-6)
    assert np.abs(first - second).max() > 1e-3


def _lod_si(rng, n, cam, first):
    """Shading points with the geometry the level of detail reads: rays of length t from the
    camera (``first``) or from elsewhere, tangents of varied length (texel size)."""
    wi, _, uv = _queries(9, n)
    si = _si(wi, uv)
    t = rng.uniform(0.5, 40.0, n).astype(np.float32)
    du, dv = rng.uniform(0.2, 3.0, (2, n)).astype(np.float32)
    origin = np.where(first[:, None], cam[None, :], cam[None, :] + [0.0, 1.5, -0.7])
    p = (origin - t[:, None] * wi).astype(np.float32)  # identity frame: to_world(wi) = wi
    si.p, si.t = mi.Point3f(p.T), mi.Float(t)
    si.dp_du, si.dp_dv = mi.Vector3f(du, 0 * du, 0 * du), mi.Vector3f(0 * dv, dv, 0 * dv)
    return si, wi, uv, t, du, dv


def test_lod_tau_per_query_equals_the_runtime_and_is_counted(material):
    """lod = auto: each lookup's τ' is the NumPy rule's (first vertex by footprint, later ones
    a fraction), the value equals RuntimeBTF.evaluate at that per-query τ' through the Dr.Jit
    kernel and through the host runtime, and the loop iterations the plugin counts per depth
    class are Σ min(count, ⌈τ'⌉)."""
    from sparsebtf.runtime.lod import (
        MIN_FRACTION,
        cone_texels_per_pixel,
        footprint_fraction,
        lod_tau,
    )

    rng = np.random.default_rng(3)
    n, cam, pixel = 400, np.array([0.5, 2.0, 6.0]), 0.004
    first = rng.uniform(size=n) < 0.6
    si, wi, uv, t, du, dv = _lod_si(rng, n, cam, first)
    wo = _dirs(rng, n)
    rt = material["rt"]
    d = {"type": "sparsebtf", "key": material["key"], "uv_scale": 2.0,
         "lod_camera": ",".join(map(str, cam)), "lod_pixel": pixel, "lod_later": 0.3,
         "lod_sampled": 0.2}  # fmt: skip
    bsdf = mi.load_dict({**d, "lod_stats": True})  # counted: the Dr.Jit kernel
    got = _eval(bsdf, si, wo)
    h, w = rt.meta["height"], rt.meta["width"]
    rho = cone_texels_per_pixel(t, pixel, wi[:, 2], du, dv, 1.0 / (h * w * 4.0))
    frac = np.where(first, footprint_fraction(rho), 0.3)
    f1 = frac[first]
    lo = MIN_FRACTION
    assert f1.min() == lo and f1.max() == 1.0 and ((f1 > lo + 0.05) & (f1 < 0.95)).sum() > 20
    tau = lod_tau(rt.tau, frac)
    ref = rt.evaluate(wo, wi, uv=uv * 2.0, tau=tau)
    np.testing.assert_allclose(got, np.maximum(ref, 0), rtol=5e-4, atol=2e-5)
    host = _eval(mi.load_dict({**d, "backend": "numba"}), si, wo)
    np.testing.assert_allclose(host, np.maximum(ref, 0), rtol=5e-4, atol=2e-5)
    full = rt.evaluate(wo, wi, uv=uv * 2.0)
    assert np.abs(full - ref).max() > 1e-2  # the level of detail changed the values
    stats = bsdf.lod_stats()
    assert stats["first_sampled"]["lookups"] == 0
    u1, u2 = rng.uniform(size=n).astype(np.float32), rng.uniform(size=(2, n)).astype(np.float32)
    bsdf.sample(mi.BSDFContext(), si, mi.Float(u1), mi.Point2f(u2))
    sampled = bsdf.lod_stats()
    # sample(): the first vertex at min(footprint fraction, lod_sampled), later ones as eval
    tau_s = lod_tau(rt.tau, np.where(first, np.minimum(frac, 0.2), 0.3))
    pts = rt._texels(uv * 2.0, None, n)[0]
    for cls, sel, st, t in (("first", first, stats, tau), ("later", ~first, stats, tau),
                            ("first_sampled", first, sampled, tau_s)):  # fmt: skip
        assert st[cls]["lookups"] == sel.sum()
        for c, ch in enumerate("YUV"):
            cnt = np.diff(rt.coded.codes[ch].offsets)[pts[sel]]
            want = np.minimum(cnt, np.ceil(t[sel, c] - 1e-4)).sum() / sel.sum()
            assert st[cls]["tau"][c] == pytest.approx(want, rel=2e-3), (cls, ch)


def test_lod_off_is_the_full_tau_plugin(material):
    """lod = off renders what lod = auto renders at fraction 1 everywhere, bit for bit (the
    per-query loop at τ' = τ is the plugin's plain loop), and auto without a camera is off."""
    opts = {"scene": "sphere", "size": (16, 16), "spp": 2, "seed": 3}
    base = {"type": "sparsebtf", "key": material["key"], "uv_scale": 3.0}
    off = render_material(base, lod="off", **opts)
    one = render_material({**base, "lod_later": 1.0, "lod_min": 1.0, "lod_sampled": 1.0},
                          lod="auto", **opts)
    low = render_material(base, lod="auto", **opts)
    assert "lod=off" in off["plugin"] and "lod=auto" in one["plugin"]
    np.testing.assert_array_equal(off.image, one.image)
    assert np.abs(low.image - off.image).max() > 0  # auto at its own fractions differs
    bare = mi.load_dict({**base, "lod": "auto"})
    assert "lod=off (auto needs lod_camera)" in str(bare)
    with pytest.raises(BTFInputError, match="lod must be one of auto, off"):
        render_material({**base, "lod": "fast"}, **opts)


def test_a_lambertian_btf_renders_as_mitsubas_diffuse():
    """The value convention (docs/format.md): a Lambertian plane of albedo ρ is the BTF
    ρ·cos θ_light in every view; the plugin must return Mitsuba's ``diffuse`` eval, ρ/π·cos θ."""
    from sparsebtf.data.btf import ArrayBTF
    from sparsebtf.data.directions import by_name

    dirs = by_name("tiny13")
    rho = np.array([0.8, 0.5, 0.2])
    cos_l = np.clip(dirs.xyz[:, 2], 0, None)
    table = np.broadcast_to(rho * cos_l[None, None, :, None, None], (2, 2, 13, 13, 3))
    key = sbm.add_material(ArrayBTF(np.ascontiguousarray(table), dirs, dirs), "test-lambert")
    plane = mi.load_dict({"type": "sparsebtf_dense", "key": key, "interpolation": "nearest"})
    diffuse = mi.load_dict({"type": "diffuse", "reflectance": {"type": "rgb", "value": rho}})
    n = len(dirs)
    light = np.repeat(dirs.xyz, n, axis=0).astype(np.float32)
    view = np.tile(dirs.xyz, (n, 1)).astype(np.float32)
    si = _si(view, np.full((n * n, 2), 0.3, np.float32))
    got = np.array(plane.eval(mi.BSDFContext(), si, mi.Vector3f(light.T))).T
    want = np.array(diffuse.eval(mi.BSDFContext(), si, mi.Vector3f(light.T))).T
    np.testing.assert_allclose(got, want, rtol=1e-4, atol=1e-6)
    assert want.max() > 0.2  # not a comparison of zeros


def _spy(rt, calls):
    """``rt.evaluate`` counting its calls (the host path's) in ``calls``."""
    plain = rt.evaluate

    def evaluate(*args, **kwargs):
        calls.append(len(args[0]))
        return plain(*args, **kwargs)

    rt.evaluate = evaluate
    return rt


def test_backend_auto_uses_the_runtime_in_evaluated_calls_only(material, monkeypatch):
    """``backend = auto``: a direct call and a render in Dr.Jit's evaluated mode reach the
    host runtime, a symbolic render (the megakernel) the Dr.Jit kernel; the renders agree, in
    one pass and in passes (the same random numbers in both modes)."""
    import sparsebtf.rendering.render as render_module

    calls = []
    key = sbm.add_material(_spy(RuntimeBTF(material["rt"].coded), calls), "test-spy")
    wi, wo, uv = _queries(4, 64)
    auto = mi.load_dict({"type": "sparsebtf", "key": key})
    got = _eval(auto, _si(wi, uv), wo)
    assert calls == [64]  # all 64 lanes active: one batch
    ref = material["rt"].evaluate(wo, wi, uv=uv)
    np.testing.assert_allclose(got, np.maximum(ref, 0), rtol=2e-5, atol=2e-6)
    jit = mi.load_dict({"type": "sparsebtf", "key": key, "backend": "drjit"})
    _eval(jit, _si(wi, uv), wo)
    assert calls == [64]
    opts = {"scene": "sphere", "size": (16, 16), "spp": 2, "seed": 5, "lod": "off"}
    plugin = {"type": "sparsebtf", "key": key, "uv_scale": 2.0, "interpolation": "linear"}
    del calls[:]
    sym = render_material(plugin, mode="symbolic", **opts)
    assert calls == [] and sym["mode"] == "symbolic"
    ev = render_material(plugin, **opts)  # auto: evaluated, the runtime answers
    assert ev["mode"] == "evaluated" and len(calls) >= 2 and sum(calls) > 100
    np.testing.assert_allclose(ev.image, sym.image, rtol=1e-4, atol=1e-6)
    assert sym.image.mean() > 0.05
    monkeypatch.setattr(render_module, "PASS_LANES", 200)  # 16·16·2 samples: 2 passes
    sym2 = render_material(plugin, mode="symbolic", **opts)
    ev2 = render_material(plugin, mode="evaluated", **opts)
    np.testing.assert_allclose(ev2.image, sym2.image, rtol=1e-4, atol=1e-6)
    assert np.abs(sym2.image - sym.image).max() > 1e-3  # other seeds: other noise


def test_backend_numba_needs_evaluated_mode_and_the_flags_come_back(material):
    flags = (dr.JitFlag.SymbolicCalls, dr.JitFlag.SymbolicLoops)
    before = [dr.flag(f) for f in flags]
    with pytest.raises(RuntimeError), sbm.evaluated():
        assert not any(dr.flag(f) for f in flags)
        raise RuntimeError("a render failed")
    assert [dr.flag(f) for f in flags] == before and all(before)
    plugin = {"type": "sparsebtf", "key": material["key"], "backend": "numba"}
    with pytest.raises(Exception) as info:
        render_material(plugin, scene="sphere", size=(8, 8), spp=1, mode="symbolic")
    chain, e = [], info.value
    while e is not None:
        chain.append(str(e))
        e = e.__cause__ or e.__context__
    assert any("backend 'numba' needs Dr.Jit's evaluated mode" in m for m in chain), chain
    with pytest.raises(BTFInputError, match="backend must be one of auto, drjit, numba"):
        preload({"type": "sparsebtf", "key": material["key"], "backend": "cuda"})
    with pytest.raises(BTFInputError, match="mode must be one of auto, symbolic, evaluated"):
        render_material({"type": "sparsebtf", "key": material["key"]}, mode="wavefront")


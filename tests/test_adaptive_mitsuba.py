"""The Mitsuba plugin on a material coded with adaptive patch sizes (issue 35): its Dr.Jit
lookup against :meth:`AdaptiveRuntimeBTF.evaluate` in nodes of each size and across node
borders, the level of detail per node, BTF-driven sampling per node, the scalar variant and
a render of an adaptive file (8x8 tiny13 material, 4x4 and 2x2 nodes).

Skips like ``tests/test_mitsuba.py`` when Mitsuba or a usable libLLVM is missing.
"""

from __future__ import annotations

import importlib.util
import json

import numpy as np
import pytest

from sparsebtf import llvm
from sparsebtf.runtime import AdaptiveRuntimeBTF

from .test_adaptive import MIXED, code_mixed, material
from .test_adaptive import model as model  # the module's fixture, reused

if importlib.util.find_spec("mitsuba") is None or importlib.util.find_spec("drjit") is None:
    pytest.skip("mitsuba/drjit not installed (pip install mitsuba drjit)", allow_module_level=True)
_status = llvm.configure()
if not _status.ok:
    pytest.skip(f"Dr.Jit LLVM backend unusable here: {_status.message()}", allow_module_level=True)

import drjit as dr  # noqa: E402
import mitsuba as mi  # noqa: E402

import sparsebtf.mitsuba as sbm  # noqa: E402
from sparsebtf.rendering.mitsuba.materials import BSDF_PER_BTF_VALUE  # noqa: E402

from .test_mitsuba import _dirs, _eval, _np, _si  # noqa: E402  (its shading points and views)

#: Texels (row, col) in 4x4 nodes, in 2x2 nodes and on both sides of the borders between
#: them (the mixed material splits blocks (0, 1) and (1, 0), rows 0-3 x cols 4-7 and the
#: mirror, into 2x2 nodes).
TEXELS = [(0, 0), (3, 3), (3, 4), (4, 3), (4, 4), (1, 6), (6, 1), (7, 7), (5, 2), (2, 5),
          (0, 3), (0, 4), (3, 7), (4, 7), (7, 3), (7, 4)]  # fmt: skip


@pytest.fixture(autouse=True)
def _llvm_variant():
    sbm.setup("llvm")
    yield


@pytest.fixture(scope="module")
def coded(model):
    return code_mixed(model)


@pytest.fixture(scope="module")
def rt(coded):
    rt = AdaptiveRuntimeBTF(coded)
    assert set(rt.coded.tree.sizes_at(*np.array(TEXELS).T).tolist()) == {2, 4}
    return rt


@pytest.fixture(scope="module")
def key(rt):
    return sbm.add_material(rt, "test-adaptive")


def _queries(seed, reps=8):
    """Each texel of :data:`TEXELS` ``reps`` times, at uv inside it (away from its borders:
    float32 against float64 floor), with random directions."""
    rng = np.random.default_rng(seed)
    tex = np.repeat(np.array(TEXELS), reps, axis=0)
    n = tex.shape[0]
    # uv: u along columns, v along rows (8x8 texels)
    uv = ((tex[:, ::-1] + rng.uniform(0.2, 0.8, (n, 2))) / 8).astype(np.float32)
    return _dirs(rng, n, 0.1), _dirs(rng, n, 0.1), uv, tex


@pytest.mark.parametrize("domain", ["standardized", "log"])
@pytest.mark.parametrize("scheme", ["linear", "barycentric", "gaussian"])
def test_eval_equals_the_adaptive_runtime(rt, key, scheme, domain):
    """eval = AdaptiveRuntimeBTF.evaluate at texels of both sizes and across node borders."""
    wi, wo, uv, _ = _queries(1)
    bsdf = mi.load_dict({"type": "sparsebtf", "key": key, "interpolation": scheme,
                         "domain": domain})  # fmt: skip
    got = _eval(bsdf, _si(wi, uv), wo)
    ref = rt.evaluate(wo, wi, uv=uv, interpolation=scheme, domain=domain, backend="numpy")
    np.testing.assert_allclose(got, np.maximum(ref, 0), rtol=2e-5, atol=2e-6)
    # the material differs between the nodes: a node read in the wrong place would show
    by_texel = ref.reshape(len(TEXELS), -1, 3).mean(axis=1)
    assert np.ptp(by_texel[:, 0]) > 0.1
    assert "adaptive {4x4:" in str(bsdf)


def test_file_tau_and_lod_fraction_of_each_nodes_tau(model, coded, rt, tmp_path):
    """By filename with a load-time tau, and with lod: every lookup at a later path vertex
    reads τ' = max(f·τ_node, min(1, τ_node)) of its node's own loaded τ (fractional), as the
    runtime with that per-query τ; lod_stats counts Σ min(count, ⌈τ'⌉) per channel."""
    from sparsebtf.storage import save_coded, save_model

    save_model(model, tmp_path / "model.h5")
    path = tmp_path / "a.coded.h5"
    save_coded(coded, path)
    wi, wo, uv, tex = _queries(2)
    n = wi.shape[0]
    d = {"type": "sparsebtf", "filename": str(path), "model": str(tmp_path / "model.h5")}
    # the file's values are binary16: its runtime, not the in-memory codes', is the reference
    full = AdaptiveRuntimeBTF.from_file(path, tmp_path / "model.h5")
    low = AdaptiveRuntimeBTF.from_file(path, tmp_path / "model.h5", tau="0.8")
    ref = np.maximum(low.evaluate(wo, wi, uv=uv), 0)
    np.testing.assert_allclose(_eval(mi.load_dict({**d, "tau": "0.8"}), _si(wi, uv), wo), ref,
                               rtol=2e-5, atol=2e-6)  # fmt: skip
    assert np.abs(full.evaluate(wo, wi, uv=uv) - ref).max() > 1e-3  # the tau was loaded
    cam = np.array([0.0, 0.0, 50.0])
    p = (np.array([3.0, -2.0, 1.0]) - 2.0 * wi).astype(np.float32)  # rays not from the camera
    f = 0.45
    bsdf = mi.load_dict({**d, "lod_camera": ",".join(map(str, cam)), "lod_later": f,
                         "lod_stats": True})  # fmt: skip
    si = _si(wi, uv)
    si.p, si.t = mi.Point3f(p.T), mi.Float(np.full(n, 2.0, np.float32))
    got = _eval(bsdf, si, wo)
    sizes = full.coded.tree.sizes_at(tex[:, 0], tex[:, 1])
    cap = np.array([[full.layers[s].tau[ch] for ch in "YUV"] for s in sizes], np.float64)
    assert len({tuple(c) for c in cap}) == 2  # the sizes' loaded τ differ
    tau = np.maximum(f * cap, np.minimum(1.0, cap))
    assert (tau != np.round(tau)).any()  # fractional levels: the last coefficient fades in
    ref = full.evaluate(wo, wi, uv=uv, tau=tau, backend="numpy")
    np.testing.assert_allclose(got, np.maximum(ref, 0), rtol=5e-4, atol=2e-5)
    assert np.abs(full.evaluate(wo, wi, uv=uv) - ref).max() > 1e-2  # the lod changed values
    # one fraction of one size's τ for every node would read other values
    small = np.array([full.layers[2].tau[ch] for ch in "YUV"], np.float64)
    wrong = full.evaluate(wo, wi, uv=uv, tau=np.broadcast_to(f * small, tau.shape),
                          backend="numpy")  # fmt: skip
    assert np.abs(wrong - ref).max() > 1e-3
    stats = bsdf.lod_stats()["later"]
    assert stats["lookups"] == n
    a = full.arrays(neighbours=False)
    node = a["cells"][tex[:, 0] // 2 + 4 * (tex[:, 1] // 2)]
    for c, ch in enumerate("YUV"):
        cnt = np.diff(a[f"offsets_{ch}"])[node]
        want = np.minimum(cnt, np.ceil(tau[:, c] - 1e-4)).sum() / n
        assert stats["tau"][c] == pytest.approx(want, rel=2e-3), ch


def test_sampling_response_is_the_texel_mean_over_nodes(rt):
    """Per node: the luminance of the geometric mean over its texels (the dense decode's);
    per material: the texel-weighted mean over the nodes."""
    from sparsebtf.colour import yuv_to_rgb
    from sparsebtf.rendering.mitsuba.sampling import dense_response
    from sparsebtf.runtime.adaptive import decoded_view
    from sparsebtf.runtime.response import LUMINANCE, angular_response, mean_log_yuv

    dec = decoded_view(rt.coded)
    z = dec.read_standardised(slice(None), slice(None), slice(None), slice(None))
    st = rt.coded.stats
    log_yuv = z * np.moveaxis(st.std, 2, -1)[None, None] + np.moveaxis(st.mean, 2, -1)[None, None]
    a = rt.arrays(neighbours=False)
    cells = a["cells"].reshape(4, 4).T  # release order: cell row fastest
    node = cells[np.arange(8)[:, None] // 2, np.arange(8)[None, :] // 2]
    n_nodes = a["node_patch"].size
    want = np.stack([log_yuv[node == j].mean(axis=0) for j in range(n_nodes)])
    got = mean_log_yuv(rt)
    np.testing.assert_allclose(got, want, atol=2e-5 * np.abs(want).max())
    per_node = angular_response(rt, per_point=True)
    assert per_node.shape == (n_nodes, 13, 13)
    rgb = np.exp(np.minimum(yuv_to_rgb(want), a["bound"][None, ..., None])) - st.log_offset
    np.testing.assert_allclose(per_node, np.maximum(rgb @ LUMINANCE, 0), rtol=1e-4, atol=1e-6)
    w = a["node_patch"].astype(np.float64) ** 2
    mean = angular_response(rt)
    np.testing.assert_allclose(mean, np.tensordot(w / w.sum(), per_node, 1), rtol=1e-5)
    assert not np.allclose(mean, per_node.mean(axis=0), rtol=1e-3)  # nodes weigh unequally
    # close to the dense decode's own response (texels' arithmetic mean of linear values)
    dense = dense_response(np.log(np.maximum(dec.to_array(), 0) + 1e-5), 1e-5)
    assert np.abs(mean - dense).max() < 0.2 * dense.max()


@pytest.mark.parametrize("tables", ["material", "patch"])
def test_btf_sampling_is_consistent_per_node(key, tables):
    """sample()'s pdf is pdf(bs.wo) bit for bit and its weight eval/pdf, with one table for
    the material or one per node; the per-node sampler equals its NumPy twin's rows."""
    from sparsebtf.rendering.mitsuba import materials, sampling
    from sparsebtf.runtime import angular_weights

    wi, _, uv, tex = _queries(3, 16)
    n = wi.shape[0]
    rng = np.random.default_rng(4)
    u1 = rng.uniform(size=n).astype(np.float32)
    u2 = rng.uniform(size=(n, 2)).astype(np.float32)
    d = {"type": "sparsebtf", "key": key, "sampling_tables": tables, "sampling_grid": 12}
    bsdf = mi.load_dict(d)
    ctx = mi.BSDFContext()
    si = _si(wi, uv)
    bs, weight = bsdf.sample(ctx, si, mi.Float(u1), mi.Point2f(u2.T))
    pdf = np.array(bsdf.pdf(ctx, si, bs.wo))
    np.testing.assert_array_equal(np.array(bs.pdf), pdf)
    wo = _np(bs.wo)
    val = _eval(bsdf, si, wo) * np.float32(BSDF_PER_BTF_VALUE)
    ok = pdf > 0
    np.testing.assert_allclose(_np(weight)[ok], val[ok] / pdf[ok, None], rtol=1e-4)
    if tables == "patch":
        rt = materials.load_runtime(("key", key))
        used = materials.coded_sampling(materials.coded_params(d), ("key", key), None, rt)
        a = rt.arrays(neighbours=False)
        assert used.cdf["radiance"].shape[0] == a["node_patch"].size  # a row per node
        idx, w = angular_weights(rt.coded.views, wi, "linear")
        node = a["cells"][tex[:, 0] // 2 + 4 * (tex[:, 1] // 2)]
        ref = sampling.sample(used, "radiance", node, idx, w, u1, u2)
        close = np.all(np.abs(wo - ref) < 1e-4, axis=1)
        assert close.mean() > 0.99, close.mean()


def test_scalar_variant(rt, key):
    """scalar_rgb: eval through AdaptiveRuntimeBTF.evaluate, per-node sampling rows as
    llvm's, and a tiny render."""
    from sparsebtf.rendering.render import render_material

    wi, wo, uv, _ = _queries(5, 1)
    wi, wo, uv = wi[::3], wo[::3], uv[::3]
    n = wi.shape[0]
    rng = np.random.default_rng(6)
    u1, u2 = rng.uniform(size=n).astype(np.float32), rng.uniform(size=(n, 2)).astype(np.float32)
    d = {"type": "sparsebtf", "key": key, "sampling_tables": "patch"}
    bs, _ = mi.load_dict(d).sample(mi.BSDFContext(), _si(wi, uv), mi.Float(u1),
                                   mi.Point2f(u2.T))  # fmt: skip
    jit_wo, jit_pdf = _np(bs.wo), np.array(bs.pdf)
    ref = rt.evaluate(wo, wi, uv=uv)
    try:
        mi.set_variant("scalar_rgb")
        sbm.register()
        b = mi.load_dict(d)
        for j in range(n):
            si = dr.zeros(mi.SurfaceInteraction3f)
            si.wi = mi.Vector3f(*wi[j])
            si.uv = mi.Point2f(*uv[j])
            got = np.array(b.eval(mi.BSDFContext(), si, mi.Vector3f(*wo[j])))
            np.testing.assert_allclose(got, np.maximum(ref[j], 0) * BSDF_PER_BTF_VALUE,
                                       rtol=1e-5, atol=1e-7)  # fmt: skip
            bs, _ = b.sample(mi.BSDFContext(), si, float(u1[j]), mi.Point2f(*u2[j]))
            np.testing.assert_allclose(np.array(bs.wo), jit_wo[j], atol=1e-4)
            np.testing.assert_allclose(bs.pdf, jit_pdf[j], rtol=1e-3)
        res = render_material({"type": "sparsebtf", "key": key}, size=(6, 6), spp=1,
                              backend="scalar")  # fmt: skip
        assert res["variant"] == "scalar_rgb" and np.all(np.isfinite(res.image))
    finally:
        sbm.setup("llvm")


def test_cli_render_of_an_adaptive_file_matches_its_dense_decode(model, coded, tmp_path,
                                                                 capsys):  # fmt: skip
    """``sparsebtf render`` reads an adaptive file: beside the dense decode of the same codes
    (same seed, same sampling tables; nearest directions in the log domain at the full τ, so
    both read the same values) it differs only by float32 rounding; beside the material it
    was coded from, by the coding error."""
    from sparsebtf.cli.main import main
    from sparsebtf.data.dense_file import write_dense
    from sparsebtf.runtime.adaptive import decoded_view
    from sparsebtf.storage import load_coded_with_model, save_coded, save_model

    save_model(model, tmp_path / "model.h5")
    path = tmp_path / "a.coded.h5"
    save_coded(coded, path)
    # the decode of the file's (binary16) values, not of the in-memory codes
    back = load_coded_with_model(path, tmp_path / "model.h5", adaptive=True)
    write_dense(tmp_path / "decoded.h5", decoded_view(back), progress=False)
    write_dense(tmp_path / "source.h5", material(MIXED), progress=False)
    mse = {}
    for ref in ("decoded", "source"):
        rc = main(["render", str(path), "-m", str(tmp_path / "model.h5"), "-o",
                   str(tmp_path / f"{ref}.png"), "--image-size", "24", "--spp", "2",
                   "--domain", "log", "--lod", "off", "--interpolation", "nearest",
                   "--reference", str(tmp_path / f"{ref}.h5"),
                   "--save-raw", str(tmp_path / f"{ref}.npz"), "--json"])  # fmt: skip
        assert rc == 0
        res = json.loads(capsys.readouterr().out)
        assert "adaptive" in res["plugin"] and res["variant"] == "llvm_ad_rgb"
        raw = np.load(tmp_path / f"{ref}.npz")
        img, want = raw["render"].astype(np.float64), raw["reference"].astype(np.float64)
        assert np.all(np.isfinite(img)) and img.mean() > 0.01
        mse[ref] = float(np.mean((img - want) ** 2) / np.mean(want**2))
    # measured: 1.4e-14 against the decode, 1.1e-3 against the source material
    assert mse["decoded"] < 1e-10, mse
    assert mse["source"] > 1e-5, mse


def test_added_materials_and_their_tau(coded, rt, key):
    """By key: an AdaptiveCodedBTF loads at the plugin's tau; an AdaptiveRuntimeBTF is cut to
    it (never raised above its loaded τ: one line), as a RuntimeBTF is."""
    from sparsebtf.errors import BTFInputError
    from sparsebtf.rendering.mitsuba import load_runtime, preload

    low = load_runtime(("key", key), "8,2,2")
    assert isinstance(low, AdaptiveRuntimeBTF)
    assert {p: r.tau for p, r in low.layers.items()} == {p: {"Y": 8, "U": 2, "V": 2}
                                                          for p in (4, 2)}  # fmt: skip
    assert rt.layers[4].tau["Y"] > 8  # the added runtime itself is unchanged
    ck = sbm.add_material(coded, "test-adaptive-coded")
    same = preload({"type": "sparsebtf", "key": ck, "tau": "8,2,2"})
    wi, wo, uv, _ = _queries(7, 1)
    np.testing.assert_allclose(same.evaluate(wo, wi, uv=uv), low.evaluate(wo, wi, uv=uv),
                               rtol=1e-6)  # fmt: skip
    cut = sbm.add_material(low, "test-adaptive-low")
    with pytest.raises(BTFInputError, match="cannot raise tau above the loaded level") as e:
        preload({"type": "sparsebtf", "key": cut, "tau": "20,2,2"})
    assert "\n" not in str(e.value)

"""The WebGL2 viewer reads a material's highlight store (issue 46): its packing as data
textures, its refusals, and the page in headless Chromium against the NumPy reference.

The material is ``test_viewer``'s small coded one with random highlight entries: at the test
scene's angular neighbour pairs (linear: 2 lights x 2 views) for about half of each point's
texels, plus random nodes elsewhere that the binary search must step over. The page's value
must equal ``max(RuntimeBTF.evaluate + correction, 0)`` (the decode of the material without the
store plus :func:`sparsebtf.learning.highlights.correction` with the runtime's own neighbours
and weights) within ``|gl − py| ≤ 1e-4·(|decode| + |correction|) + 1e-5``. One query sits on a
stored node (sampled light and view: one-hot weights) whose correction is large, so a shader
that misses the store fails. Browser tests skip as ``test_viewer``'s do.

Per-texel lobes (:mod:`sparsebtf.learning.lobes`): random lobes on every texel, with and
without the entries, against ``max(decode + correction + lobe, 0)``, the lobe from
:func:`sparsebtf.learning.highlights.lobe_corrections` at the query's directions (the runtime's
``evaluate`` is not relied on for it). Texel (0, 0) of point 0 has its normal on the scene's
half vector, a lobe far above the decode, so a shader that drops the lobe fails.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import replace

import numpy as np
import pytest

from sparsebtf.errors import BTFInputError
from sparsebtf.learning.highlights import Highlights, correction, lobe_corrections, node_keys
from sparsebtf.learning.lobes import LOBE_PARAMS
from sparsebtf.points.grid import PatchGrid
from sparsebtf.rendering.viewer import build_bundle, export, pack_textures, serve
from sparsebtf.runtime import RuntimeBTF, angular_weights
from sparsebtf.runtime.decoder import query_texels

from .test_highlight_decode import random_lobes
from .test_viewer import (
    ATOL,
    RTOL,
    SIZE,
    WI,
    WO,
    open_test_scene,
    read_image,
    static_server,
)
from .test_viewer import browser as browser  # the module's fixtures, reused
from .test_viewer import coded as coded
from .test_viewer import model as model

#: Correction of the stored node the on-node check reads at texel (0, 0): far above the decode.
BIG = 6.0
#: Random extra nodes per point (beside the scene's), for the binary search to step over.
EXTRA = 40


def _scene_nodes(coded) -> tuple[np.ndarray, np.ndarray]:
    """Light and view indices of the test scene's linear neighbours of WI and WO (2 each)."""
    li, _ = angular_weights(coded.lights, WI[None], "linear")
    vi, _ = angular_weights(coded.views, WO[None], "linear")
    return li[0], vi[0]


def random_store(coded, seed: int = 7) -> Highlights:
    """Entries at the scene's neighbour pairs for about half the texels of every point, the
    pair (light li[0], view vi[0]) of texel (0, 0) of point 0 = :data:`BIG` per channel, and
    :data:`EXTRA` random nodes per point; corrections in [-1.5, 2.5] (some values clamp at 0)."""
    rng = np.random.default_rng(seed)
    p, n_l, n_v = coded.patch, len(coded.lights), len(coded.views)
    li, vi = _scene_nodes(coded)
    i1, i2, a, b = np.meshgrid(np.arange(p), np.arange(p), li, vi, indexing="ij")
    scene = node_keys(i1, i2, a, b, p, n_l, n_v).reshape(p * p, -1)  # (texel, pair)
    points, keys = [], []
    for pt in range(coded.n_points):
        chosen = scene[rng.random(p * p) < 0.5].ravel()
        extra = rng.choice(p * p * n_l * n_v, EXTRA, replace=False)
        k = np.union1d(chosen, extra)
        if pt == 0:
            k = np.union1d(k, scene[0, :1])
        points.append(np.full(k.size, pt))
        keys.append(k)
    points, keys = np.concatenate(points), np.concatenate(keys)
    rgb = rng.uniform(-1.5, 2.5, (keys.size, 3))
    rgb[(points == 0) & (keys == scene[0, 0])] = BIG
    return Highlights.from_nodes(points, keys, rgb, coded.n_points)


def pinned_lobes(coded, wi: np.ndarray = WI, wo: np.ndarray = WO, seed: int = 3) -> np.ndarray:
    """``random_lobes`` with texel (0, 0) of point 0 turning its normal onto the half vector of
    ``wi``, ``wo``, α = 0.1 and amplitude 1 (a value of about 40 there)."""
    lobes = random_lobes(coded, np.random.default_rng(seed)).astype(np.float64)
    h = (wi + wo) / np.linalg.norm(wi + wo)
    k = np.cross([0.0, 0.0, 1.0], h)  # e_z x h: the axis that turns e_z onto h
    lobes[0, 0] = [*(k / np.linalg.norm(k) * np.arccos(h[2])), np.log(0.1), np.log(0.1), 1, 1, 1]
    return lobes.astype(np.float16)


@pytest.fixture(scope="module")
def store(coded):
    return random_store(coded)


@pytest.fixture(scope="module")
def rt_plain(coded):
    return RuntimeBTF(replace(coded, highlights=None))


@pytest.fixture(scope="module")
def rt_hl(coded, store):
    return RuntimeBTF(replace(coded, highlights=store))


def scene_queries(coded, wi: np.ndarray, wo: np.ndarray, interp: str):
    """The test scene's uv (SIZE², 2), its texels (point, i1, i2) and the neighbours and
    weights of ``wi``, ``wo`` for every pixel (readPixels order)."""
    j, i = np.meshgrid(np.arange(SIZE), np.arange(SIZE), indexing="ij")
    uv = np.stack([(i.ravel() + 0.5) / SIZE, (j.ravel() + 0.5) / SIZE], axis=1)
    row, col = query_texels(uv, None, coded.height, coded.width)
    pts, i1, i2 = PatchGrid(coded.height, coded.width, coded.patch).locate(row, col)
    n = uv.shape[0]
    li, lw = angular_weights(coded.lights, np.tile(wi, (n, 1)), interp)
    vi, vw = angular_weights(coded.views, np.tile(wo, (n, 1)), interp)
    return uv, (pts, i1, i2), (li, lw, vi, vw)


def hl_reference(rt_plain, store, wi, wo, interp="linear", domain="standardized"):
    """(decode, correction, max(decode + correction, 0)), each (SIZE, SIZE, 3) float64."""
    coded = rt_plain.coded
    uv, (pts, i1, i2), (li, lw, vi, vw) = scene_queries(coded, wi, wo, interp)
    n = uv.shape[0]
    dec = rt_plain.evaluate(np.tile(wi, (n, 1)), np.tile(wo, (n, 1)), uv=uv,
                            interpolation=interp, domain=domain).astype(np.float64)  # fmt: skip
    corr = correction(store, pts, i1, i2, li, lw, vi, vw, coded.patch, len(coded.lights),
                      len(coded.views))  # fmt: skip
    shape = (SIZE, SIZE, 3)
    return dec.reshape(shape), corr.reshape(shape), np.maximum(dec + corr, 0.0).reshape(shape)


def lobe_reference(rt_plain, store, wi, wo, interp="linear", domain="standardized"):
    """As :func:`hl_reference` with the store's lobes at (wi, wo) added before the clamp:
    (decode, correction + lobe, clamped sum, lobe), each (SIZE, SIZE, 3) float64."""
    coded = rt_plain.coded
    dec, corr, _ = hl_reference(rt_plain, store, wi, wo, interp, domain)
    _, (pts, i1, i2), _ = scene_queries(coded, wi, wo, interp)
    lobe = lobe_corrections(store, pts, i1 * coded.patch + i2, wi[None], wo[None])
    lobe = lobe.reshape(dec.shape)
    return dec, corr + lobe, np.maximum(dec + corr + lobe, 0.0), lobe


def assert_hl_close(gl: np.ndarray, dec: np.ndarray, corr: np.ndarray, py: np.ndarray) -> None:
    """The tolerance of ``test_viewer`` on the decode's and the correction's magnitudes (the
    sum can cancel to near 0, where only the addends' float32 rounding bounds the error)."""
    assert np.all(np.isfinite(gl))
    bad = np.abs(gl - py) > RTOL * (np.abs(dec) + np.abs(corr)) + ATOL
    assert not bad.any(), (
        f"{bad.sum()} of {bad.size} values differ; max |gl - py| = {np.abs(gl - py).max():.3g}"
    )


# -- packing (no browser) -----------------------------------------------------------------------
def _tex(bundle, name: str, dtype: str, comps: int = 1) -> np.ndarray:
    t = bundle.manifest["textures"][name]
    return np.frombuffer(bundle.data, dtype, t["entries"] * comps, t["offset"])


def test_bundle_carries_the_store(rt_hl, store):
    bundle = build_bundle(rt_hl, neighbours=False)
    m = bundle.manifest
    assert m["uniforms"]["sb_highlights"] == 1 and m["highlights"] == store.n_entries
    assert m["textures"]["sb_hlRgb"]["format"] == "RGB16F"
    assert np.array_equal(_tex(bundle, "sb_hlOffsets", "<u4"), store.offsets)
    assert np.array_equal(_tex(bundle, "sb_hlKeys", "<u4"), store.keys)
    rgb = _tex(bundle, "sb_hlRgb", "<f2", 3).reshape(-1, 3)
    assert np.array_equal(rgb.view(np.uint16), store.rgb.view(np.uint16))  # bits as stored


def test_no_store_changes_nothing(coded, rt_plain):
    plain = build_bundle(rt_plain, neighbours=False)
    empty = build_bundle(RuntimeBTF(replace(coded, highlights=Highlights.empty(coded.n_points))),
                         neighbours=False)  # fmt: skip
    assert empty.data == plain.data and empty.manifest == plain.manifest
    assert "highlights" not in plain.manifest and "sb_highlights" not in plain.manifest["uniforms"]
    assert not any(t.startswith("sb_hl") for t in plain.manifest["textures"])


def test_packing_refuses_a_store_that_does_not_fit(rt_hl, store):
    arr = rt_hl.arrays(neighbours=False)  # the store's arrays among them
    bad = dict(arr, highlight_keys=arr["highlight_keys"].copy())
    c = rt_hl.coded
    past = c.patch**2 * len(c.lights) * len(c.views)  # one past the last node
    bad["highlight_keys"][-1] = past
    with pytest.raises(BTFInputError, match=rf"stone.h5: key {past} at entry \d+ is outside"):
        pack_textures(bad, rt_hl.meta, "stone.h5")
    del arr["highlight_rgb"]
    with pytest.raises(BTFInputError, match="highlight store incomplete, missing highlight_rgb"):
        pack_textures(arr, rt_hl.meta, "stone.h5")


# -- the page in headless Chromium --------------------------------------------------------------
@contextmanager
def served_page(browser, rt: RuntimeBTF) -> Iterator:
    """The test scene of ``rt``'s bundle, served, in a page closed afterwards."""
    with serve(build_bundle(rt)) as srv:
        page = open_test_scene(browser, srv.url)
        try:
            yield page
        finally:
            page.close()


@pytest.fixture(scope="module")
def hl_page(browser, rt_hl):
    with served_page(browser, rt_hl) as page:
        yield page


@pytest.mark.parametrize(("interp", "domain", "neigh"), [
    ("linear", "standardized", True),
    ("linear", "log", False),
    ("barycentric", "standardized", True),
])  # fmt: skip
def test_page_adds_the_interpolated_corrections(hl_page, rt_plain, store, interp, domain, neigh):
    gl = read_image(hl_page, interp=interp, domain=domain, neigh=neigh, lod=1.0,
                    wi=WI.tolist(), wo=WO.tolist())  # fmt: skip
    dec, corr, py = hl_reference(rt_plain, store, WI, WO, interp, domain)
    assert np.abs(corr).max() > 0.3 and (corr == 0).any()  # corrected and plain texels
    assert (dec + corr < -1e-3).any()  # the clamp at 0 is at work
    assert_hl_close(gl, dec, corr, py)


def test_page_at_a_stored_node_gives_decode_plus_its_correction(hl_page, rt_plain, store):
    """At a sampled light and view (one-hot weights) texel (0, 0) of point 0 reads its stored
    node: decode + BIG exactly (in float32), far from the plain decode."""
    li, vi = _scene_nodes(rt_plain.coded)
    wi, wo = rt_plain.coded.lights.xyz[li[0]], rt_plain.coded.views.xyz[vi[0]]
    gl = read_image(hl_page, interp="linear", domain="standardized", neigh=True, lod=1.0,
                    wi=wi.tolist(), wo=wo.tolist())  # fmt: skip
    dec, corr, py = hl_reference(rt_plain, store, wi, wo)
    assert_hl_close(gl, dec, corr, py)
    # texel (0, 0) is the bottom-left 8x8 pixels of the 64x64 scene (8 pixels per texel)
    assert np.allclose(corr[:8, :8], BIG)
    assert np.all(gl[:8, :8] - dec[:8, :8] > BIG - 1e-3)


def test_static_export_carries_the_store(browser, rt_hl, rt_plain, store, tmp_path):
    out = export(build_bundle(rt_hl), tmp_path / "site")
    with static_server(out) as url:
        page = open_test_scene(browser, url)
        gl = read_image(page, interp="nearest")
        page.close()
    dec, corr, py = hl_reference(rt_plain, store, WI, WO, "nearest")
    assert np.abs(corr).max() > 0.3
    assert_hl_close(gl, dec, corr, py)


# -- per-texel lobes ----------------------------------------------------------------------------
@pytest.fixture(scope="module")
def lobes(coded):
    return pinned_lobes(coded)


@pytest.fixture(scope="module")
def store_lobes(store, lobes):
    """The entries of :func:`random_store` and a lobe on every texel."""
    return replace(store, lobes=lobes)


@pytest.fixture(scope="module")
def lobes_only(coded, lobes):
    return replace(Highlights.empty(coded.n_points), lobes=lobes)


def test_bundle_carries_the_lobes(coded, store_lobes, lobes_only, lobes):
    rows = lobes.reshape(-1, LOBE_PARAMS)
    for h in (store_lobes, lobes_only):
        bundle = build_bundle(RuntimeBTF(replace(coded, highlights=h)), neighbours=False)
        m = bundle.manifest
        assert m["uniforms"]["sb_lobes"] == 1 and m["lobes"] == rows.shape[0]
        assert m["textures"]["sb_hlLobes"]["format"] == "RGBA16F"
        got = _tex(bundle, "sb_hlLobes", "<f2", 4).reshape(-1, LOBE_PARAMS)  # 2 texels a lobe
        assert np.array_equal(got.view(np.uint16), rows.view(np.uint16))  # bits as stored
    # lobes and no entries: no (empty) entry textures, no search
    m = build_bundle(RuntimeBTF(replace(coded, highlights=lobes_only)), neighbours=False).manifest
    assert "sb_highlights" not in m["uniforms"] and "highlights" not in m
    assert not any(t in m["textures"] for t in ("sb_hlOffsets", "sb_hlKeys", "sb_hlRgb"))


def test_packing_refuses_lobes_that_do_not_fit(coded, lobes_only):
    rt = RuntimeBTF(replace(coded, highlights=lobes_only))
    arr = rt.arrays(neighbours=False)
    bad = dict(arr, highlight_lobes=arr["highlight_lobes"][1:])
    with pytest.raises(BTFInputError, match=r"stone.h5: highlight_lobes has shape"):
        pack_textures(bad, rt.meta, "stone.h5")
    neg = dict(arr, highlight_lobes=arr["highlight_lobes"].copy())
    neg["highlight_lobes"][5, 6] = -1.0  # row 5: point 5 // p², texel 5 % p²
    pt, tx = divmod(5, coded.patch**2)
    with pytest.raises(BTFInputError, match=rf"lobe of point {pt}, texel {tx} .*negative"):
        pack_textures(neg, rt.meta, "stone.h5")


def _check_lobe_page(page, rt_plain, h, wi, wo, interp, domain="standardized", neigh=True):
    gl = read_image(page, interp=interp, domain=domain, neigh=neigh, lod=1.0,
                    wi=wi.tolist(), wo=wo.tolist())  # fmt: skip
    dec, corr, py, lobe = lobe_reference(rt_plain, h, wi, wo, interp, domain)
    assert_hl_close(gl, dec, corr, py)
    return gl, dec, lobe


@pytest.fixture(scope="module")
def lobe_page(browser, coded, store_lobes):
    with served_page(browser, RuntimeBTF(replace(coded, highlights=store_lobes))) as page:
        yield page


@pytest.mark.parametrize(("interp", "domain", "neigh"), [
    ("linear", "standardized", True),
    ("barycentric", "log", False),
])  # fmt: skip
def test_page_adds_corrections_and_lobes(lobe_page, rt_plain, store_lobes, interp, domain, neigh):
    gl, dec, lobe = _check_lobe_page(lobe_page, rt_plain, store_lobes, WI, WO, interp, domain,
                                     neigh)  # fmt: skip
    # the lobe peaks at texel (0, 0) (bottom-left 8x8 pixels) and is > 0.01 on many texels
    assert lobe[:8, :8].min() > 10 and np.all(gl[:8, :8] - dec[:8, :8] > 10)
    assert (lobe > 1e-2).mean() > 0.1


def test_page_adds_lobes_without_entries(browser, coded, rt_plain, lobes_only):
    """A store of lobes only, at the scene's directions and at others (the lobe follows the
    fragment's own wi, wo: another half vector lights other texels)."""
    with served_page(browser, RuntimeBTF(replace(coded, highlights=lobes_only))) as page:
        gl, dec, lobe = _check_lobe_page(page, rt_plain, lobes_only, WI, WO, "linear")
        assert np.all(gl[:8, :8] - dec[:8, :8] > 10)
        wi = np.array([-0.5, 0.3, 0.8]) / np.linalg.norm([-0.5, 0.3, 0.8])
        wo = np.array([0.2, -0.6, 0.7]) / np.linalg.norm([0.2, -0.6, 0.7])
        _, _, lobe2 = _check_lobe_page(page, rt_plain, lobes_only, wi, wo, "nearest")
        page.close()
    assert (lobe2 > 1e-2).mean() > 0.1 and not np.allclose(lobe, lobe2)


def test_static_export_carries_the_lobes(browser, coded, rt_plain, store_lobes, tmp_path):
    out = export(build_bundle(RuntimeBTF(replace(coded, highlights=store_lobes))),
                 tmp_path / "site")  # fmt: skip
    with static_server(out) as url:
        page = open_test_scene(browser, url)
        _, _, lobe = _check_lobe_page(page, rt_plain, store_lobes, WI, WO, "nearest")
        page.close()
    assert lobe[:8, :8].min() > 10

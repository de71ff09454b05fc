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
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from sparsebtf.errors import BTFInputError
from sparsebtf.learning.highlights import Highlights, correction, node_keys
from sparsebtf.points.grid import PatchGrid
from sparsebtf.rendering.viewer import build_bundle, export, pack_textures, serve
from sparsebtf.runtime import RuntimeBTF, angular_weights
from sparsebtf.runtime.decoder import query_texels

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
@pytest.fixture(scope="module")
def hl_page(browser, rt_hl):
    with serve(build_bundle(rt_hl)) as srv:
        page = open_test_scene(browser, srv.url)
        yield page
        page.close()


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

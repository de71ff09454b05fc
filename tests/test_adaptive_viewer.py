"""The WebGL2 viewer on a material coded with adaptive patch sizes (issue 35): the packing of
the tree (texel-to-node table, node classes), its refusals, the ``view`` command, and the page
in headless Chromium against :meth:`AdaptiveRuntimeBTF.evaluate`.

The material is ``test_adaptive``'s mixed one: 8x8 texels, two 4x4 nodes and eight 2x2 nodes.
The page's 64x64 test scene shows every texel as an 8x8 block of pixels, so each image holds
texels in nodes of both sizes and on both sides of every border between them; it must match
the runtime within ``test_viewer``'s tolerance. Browser tests skip as ``test_viewer``'s do.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from sparsebtf.errors import BTFInputError
from sparsebtf.rendering import viewer
from sparsebtf.rendering.viewer import ViewerBundle, build_bundle, pack_textures
from sparsebtf.runtime import AdaptiveRuntimeBTF, RuntimeBTF
from sparsebtf.runtime.lod import footprint_fraction

from .test_adaptive import _rewrite_nodes, code_mixed
from .test_adaptive import model as model  # the module's fixtures, reused
from .test_viewer import (
    PAGE_CASES,
    SIZE,
    WI,
    WO,
    assert_close,
    check_page,
    open_test_scene,
    read_image,
    reference,
    saved,
    served_test_scene,
    static_server,
)
from .test_viewer import browser as browser

TREE_RECORD = 4  # int32 components of an sb_points record


@pytest.fixture(scope="module")
def coded(model):
    return code_mixed(model)


@pytest.fixture(scope="module")
def rt(coded):
    return AdaptiveRuntimeBTF(coded)


@pytest.fixture(scope="module")
def files(model, coded, tmp_path_factory):
    return saved(tmp_path_factory.mktemp("adaptive_viewer"), model, coded)


def _texture(bundle, name: str, dtype: str, comps: int = 1) -> np.ndarray:
    t = bundle.manifest["textures"][name]
    return np.frombuffer(bundle.data, dtype, t["entries"] * comps, t["offset"])


def _node_caps(rt: AdaptiveRuntimeBTF) -> np.ndarray:
    """(SIZE·SIZE, 3) loaded τ of the node under each test-scene pixel (readPixels order)."""
    a = rt.arrays(neighbours=False)
    j, i = np.meshgrid(np.arange(SIZE), np.arange(SIZE), indexing="ij")
    row, col = (j.ravel() * 8) // SIZE, (i.ravel() * 8) // SIZE
    node = a["cells"][row // 2 + 4 * (col // 2)]
    return np.stack([a[f"tau_{c}"][node] for c in "YUV"], axis=1).astype(np.float64)


# -- packing (no browser) -------------------------------------------------------------------
def test_manifest_holds_the_tree(rt, coded):
    bundle = build_bundle(rt)
    a = rt.arrays()
    m = json.loads(json.dumps(bundle.manifest))  # what the page reads
    tree = coded.tree
    assert m["uniforms"]["sb_adaptive"] == [1, 2, 4, 2]  # flag, s, H/s, classes
    assert m["uniforms"]["sb_size"] == [8, 8, 4, 2]  # the largest size: the dictionaries' stride
    assert m["uniforms"]["sb_counts"][0] == tree.n_nodes == 10
    assert m["uniforms"]["sb_dictSize"][:2] == [4, 4]
    ad = m["adaptive"]
    assert ad["sizes"] == [4, 2] and ad["smallest"] == 2 and ad["nodes"] == {"4": 2, "2": 8}
    assert ad["classes"] == [[4, *rt.layers[4].tau.values()], [2, *rt.layers[2].tau.values()]]
    assert m["meta"]["nnz"] == {c: int(a[f"values_{c}"].size) for c in "YUV"}
    # the texel-to-node table and each node's class, read back from the binary
    np.testing.assert_array_equal(_texture(bundle, "sb_tree", "<i4"), a["cells"])
    rec = _texture(bundle, "sb_points", "<i4", TREE_RECORD).reshape(3, tree.n_nodes, 4)
    classes = np.array(ad["classes"])[rec[0, :, 3]]
    np.testing.assert_array_equal(classes[:, 0], a["node_patch"])
    for c, ch in enumerate("YUV"):
        np.testing.assert_array_equal(rec[c, :, 3], rec[0, :, 3])
        np.testing.assert_array_equal(classes[:, 1 + c], a[f"tau_{ch}"])
        np.testing.assert_array_equal(rec[c, :, 2], a[f"membership_{ch}"])


def test_page_and_shader_hold_as_many_classes_as_the_packing():
    from sparsebtf.rendering.viewer.tree import MAX_CLASSES

    files = ViewerBundle({"data": "data.bin"}, b"").files()  # the page's static files
    assert f"#define SB_MAX_CLASSES {MAX_CLASSES}\n" in files["sparsebtf_lookup.glsl"].decode()
    assert f"const MAX_CLASSES = {MAX_CLASSES};" in files["viewer.js"].decode()


def test_fixed_size_manifest_has_no_tree(rt):
    fixed = rt.layers[4]  # the 4x4 layer: an ordinary coded BTF of one patch size
    assert isinstance(fixed, RuntimeBTF)
    bundle = build_bundle(fixed)
    m = bundle.manifest
    assert "sb_tree" not in m["textures"] and "adaptive" not in m
    assert "sb_adaptive" not in m["uniforms"] and m["uniforms"]["sb_counts"][0] == 4
    assert not _texture(bundle, "sb_points", "<i4", TREE_RECORD)[3::4].any()


@pytest.mark.parametrize(("change", "says"), [
    ("cells", "cell 5 names node 10, outside the 10 nodes"),
    ("cells_shape", "cells of shape (15,)"),
    ("size", "node 3 has size 3, expected a divisor of 4 and a multiple of 2"),
    ("tau", "adaptive patch sizes need the arrays tau_U"),
    ("classes", "3 distinct (node size, tau) pairs, the viewer's shader holds 2"),
])  # fmt: skip
def test_hostile_arrays_are_one_line(rt, monkeypatch, change, says):
    a, meta = rt.arrays(neighbours=False), rt.flat_meta
    if change == "cells":
        a["cells"] = a["cells"].copy()
        a["cells"][5] = 10
    elif change == "cells_shape":
        a["cells"] = a["cells"][:-1]
    elif change == "size":
        a["node_patch"] = a["node_patch"].copy()
        a["node_patch"][3] = 3
    elif change == "tau":
        del a["tau_U"]
    else:
        monkeypatch.setattr(viewer.tree, "MAX_CLASSES", 2)
        a["tau_Y"] = a["tau_Y"].copy()
        a["tau_Y"][-1] -= 1  # a third class
    with pytest.raises(BTFInputError) as e:
        pack_textures(a, meta, "m.h5")
    text = str(e.value)
    assert "\n" not in text and text.startswith("m.h5: ") and says in text


def test_oversized_adaptive_material_is_one_line(rt, monkeypatch):
    monkeypatch.setattr(viewer, "MAX_TEX_HEIGHT", 1)  # the dictionaries of both sizes: 2 rows
    with pytest.raises(BTFInputError) as e:
        build_bundle(rt, neighbours=False)
    text = str(e.value)
    assert "\n" not in text
    assert "busy: texture sb_dicts needs 6660 texels = 4096x2, above the 4096x1 limit" in text


def test_view_command_refuses_a_hostile_tree_in_one_line(files, tmp_path, capsys):
    from sparsebtf.cli.main import main
    from sparsebtf.storage import load_coded

    coded = load_coded(files / "coded.h5", adaptive=True)
    nodes = coded.tree.nodes.copy()
    small = np.flatnonzero(nodes[:, 2] == 2)
    nodes[small[0], :2] = nodes[small[1], :2]  # two nodes on one place
    _rewrite_nodes(files / "coded.h5", tmp_path / "bad.h5", nodes)
    assert main(["view", str(tmp_path / "bad.h5"), "-m", str(files / "model.h5"),
                 "--export", str(tmp_path / "site")]) == 2  # fmt: skip
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "overlap" in err
    assert not (tmp_path / "site").exists()


# -- the page in headless Chromium --------------------------------------------------------------
@pytest.fixture(scope="module")
def test_page(browser, rt):
    yield from served_test_scene(browser, rt)


@pytest.mark.parametrize(("interp", "domain", "neigh"), PAGE_CASES)
def test_page_matches_the_adaptive_runtime(test_page, rt, interp, domain, neigh):
    check_page(test_page, rt, interp, domain, neigh)


def test_lod_is_a_fraction_of_each_nodes_tau(test_page, rt):
    """The slider at 30 % caps each node at ⌈0.3·τ_node⌉ (the runtime's per-query τ; 0.3 makes
    no product an integer, so rounding down would show), the ramp and the footprint take their
    fraction of that cap, as sparsebtf.runtime.lod does."""
    caps = _node_caps(rt)
    full = read_image(test_page, interp="linear", domain="standardized", lod=1.0, ramp=False,
                      footprint=True, zoom=1.0)  # fmt: skip
    test_page.locator("#tau").fill("300")  # the slider, as a user drags it
    assert test_page.evaluate("window.sparsebtf.state.lod") == 0.3
    cap30 = np.ceil(0.3 * caps)  # τ (22, 16, 16) of the 4x4 nodes, (16, 4, 4) of the 2x2 ones
    assert {tuple(r) for r in cap30} == {(7, 5, 5), (5, 2, 2)}  # both sizes in the image
    text = test_page.locator("#tauText").inner_text()
    assert "4×4 7, 5, 5" in text and "2×2 5, 2, 2" in text
    low = read_image(test_page)
    py = reference(rt, interpolation="linear", tau=cap30)
    assert np.abs(py - full).max() > 0.01 * np.abs(full).max()
    assert_close(low, py)
    # fractional tau' per fragment: (x + 0.5) / 64 of each node's cap across the image
    j, i = np.meshgrid(np.arange(SIZE), np.arange(SIZE), indexing="ij")
    f = ((i + 0.5) / SIZE).ravel()[:, None]
    ramp = read_image(test_page, ramp=True)
    assert_close(ramp, reference(rt, interpolation="linear",
                                 tau=np.maximum(f * cap30, np.minimum(1.0, cap30))))  # fmt: skip
    # the footprint: the texture zoomed 11x, rho = 11·8/64 texels per pixel side
    zoom = 11.0
    shot = read_image(test_page, ramp=False, zoom=zoom, footprint=True)
    uv = np.stack([(i.ravel() + 0.5) / SIZE, (j.ravel() + 0.5) / SIZE], axis=1) * zoom
    row, col = (np.floor(uv[:, 1] * 8) % 8).astype(int), (np.floor(uv[:, 0] * 8) % 8).astype(int)
    a = rt.arrays(neighbours=False)
    node = a["cells"][row // 2 + 4 * (col // 2)]
    cap = np.ceil(0.3 * np.stack([a[f"tau_{c}"][node] for c in "YUV"], axis=1))
    ff = footprint_fraction(zoom * 8 / SIZE)
    n = uv.shape[0]
    want = rt.evaluate(np.tile(WI, (n, 1)), np.tile(WO, (n, 1)), uv=uv,
                       tau=np.maximum(ff * cap, np.minimum(1.0, cap)))  # fmt: skip
    assert_close(shot, want.reshape(SIZE, SIZE, 3))
    read_image(test_page, zoom=1.0, lod=1.0)


def test_view_export_of_an_adaptive_file_loads_from_plain_http(browser, files, tmp_path, capsys):
    from sparsebtf.cli.main import main

    out = tmp_path / "site"
    assert main(["view", str(files / "coded.h5"), "-m", str(files / "model.h5"),
                 "--export", str(out)]) == 0  # fmt: skip
    assert f"wrote {out}/" in capsys.readouterr().out
    assert json.loads((out / "manifest.json").read_text())["adaptive"]["nodes"] == {"4": 2, "2": 8}
    with static_server(out) as url:
        page = open_test_scene(browser, url)
        assert "adaptive patches 2 of 4x4, 8 of 2x2" in page.locator("#info").inner_text()
        back = AdaptiveRuntimeBTF.from_file(files / "coded.h5", files / "model.h5")  # float16
        assert_close(read_image(page, interp="nearest"), reference(back, interpolation="nearest"))
        page.close()

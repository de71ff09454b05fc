"""Adaptive patch sizes (issue 35, first slice): models with several patch sizes, the rate and
distortion quadtree, schema 4 files and the NumPy decoders, on 8x8 tiny13 materials with
4x4 and 2x2 patches."""

from __future__ import annotations

import h5py
import numpy as np
import pytest

from sparsebtf.codec import train
from sparsebtf.codec.adaptive import encode_adaptive
from sparsebtf.codec.options import TrainOptions
from sparsebtf.data.btf import ArrayBTF
from sparsebtf.data.directions import tiny
from sparsebtf.errors import BTFInputError, FileFormatError, SparseBTFError
from sparsebtf.learning.coding import reconstruct_points
from sparsebtf.model import Model, dictionaries_hash
from sparsebtf.patch_tree import AdaptiveCodedBTF, PatchTree
from sparsebtf.points.preprocessing import Preprocessor
from sparsebtf.runtime import AdaptiveRuntimeBTF, RuntimeBTF
from sparsebtf.runtime.adaptive import decoded_view
from sparsebtf.runtime.kernels import HAVE_NUMBA
from sparsebtf.storage import load_coded, load_coded_with_model, load_model, save_coded, save_model

from .conftest import smooth_btf

#: The blocks (row, col) of 4x4 texels that are busy in the mixed material.
MIXED = ((0, 1), (1, 0))


@pytest.fixture(scope="module")
def model():
    btfs = [smooth_btf(s) for s in range(3)]
    return train(btfs, n_dictionaries=3, tau_train=(16, 4, 4), patch=(4, 2), sample=1.0,
                 max_iter=1, progress=False)  # fmt: skip


def _pattern(e: float, cos: np.ndarray) -> np.ndarray:
    return ((0.2 + cos) ** e)[:, None] * ((0.3 + cos) ** (2 - e))[None, :]


def material(busy: tuple[tuple[int, int], ...], seed: int = 3) -> ArrayBTF:
    """8x8 texels in four 4x4 blocks: a smooth block is one colour and angular behaviour;
    a busy one has another of each in every 2x2 quarter."""
    d = tiny(13)
    rng = np.random.default_rng(seed)
    cos = d.xyz[:, 2]
    data = np.empty((8, 8, 13, 13, 3), np.float32)
    smooth = 0.4 * _pattern(1.0, cos)[..., None] * np.array([0.6, 0.5, 0.4])
    for r in range(4):
        for c in range(4):
            if (r // 2, c // 2) in busy:
                v = _pattern(rng.uniform(0, 2), cos)[..., None] * rng.uniform(0.05, 1, 3)
            else:
                v = smooth
            data[2 * r:2 * r + 2, 2 * c:2 * c + 2] = v
    return ArrayBTF(data, d, d, name="busy" if busy else "smooth")


def code_mixed(model: Model) -> AdaptiveCodedBTF:
    """The mixed material coded adaptively at 1500 Table 4 bytes (nodes of both sizes); the
    adaptive test files share it."""
    return encode_adaptive(material(MIXED), model, (64, 16, 16), target_bytes=1500,
                           progress=False)  # fmt: skip


@pytest.fixture(scope="module")
def mixed(model, tmp_path_factory):
    """The mixed material coded adaptively (:func:`code_mixed`), saved and read back."""
    coded = code_mixed(model)
    folder = tmp_path_factory.mktemp("adaptive")
    save_model(model, folder / "model.h5")  # the coded file records it and finds it again
    path = folder / "mixed.coded.h5"
    save_coded(coded, path)
    return coded, path


def _one_line(e: pytest.ExceptionInfo) -> str:
    text = str(e.value)
    assert "\n" not in text and text
    return text


# -- models ---------------------------------------------------------------------------------


def test_model_of_two_sizes_round_trips(model, tmp_path):
    assert model.patch_sizes == (4, 2) and model.mode_sizes == (4, 4, 13, 13)
    assert model.for_patch(2).mode_sizes == (2, 2, 13, 13)
    assert model.for_patch(2).content_hash == model.content_hash  # codes name the whole model
    assert model.content_hash != dictionaries_hash(model.dictionaries)
    path = save_model(model, tmp_path / "m.h5")
    back = load_model(path)
    assert back.patch_sizes == (4, 2) and back.content_hash == model.content_hash
    for ch in model.channels:
        for a, b in zip(model.patches[2][ch], back.patches[2][ch], strict=True):
            np.testing.assert_array_equal(a, b)
    with h5py.File(path) as f:
        assert int(f.attrs["schema_version"]) == 3
    one = Model(model.dictionaries, 4, model.lights, model.views, dict(model.params))
    path1 = save_model(one, tmp_path / "one.h5")  # one size: schema 2, the hash as before
    with h5py.File(path1) as f:
        assert int(f.attrs["schema_version"]) == 2
    assert load_model(path1).content_hash == dictionaries_hash(model.dictionaries)


def test_patch_sizes_must_nest():
    with pytest.raises(BTFInputError) as e:
        TrainOptions(patch=(4, 3))
    assert "3 does not divide 4" in _one_line(e)
    with pytest.raises(BTFInputError) as e:
        TrainOptions(patch="20,x")
    _one_line(e)
    assert TrainOptions(patch="20,10,5").patch == "20,10,5"


def test_release_model_stays_one_size():
    from sparsebtf.api import load_model as api_load

    release = api_load("release")
    assert release.patch_sizes == (10,) and not release.patches
    assert release.content_hash == dictionaries_hash(release.dictionaries)
    with pytest.raises(SparseBTFError) as e:
        encode_adaptive(smooth_btf(1, size=10, n_dirs=13), release)
    _one_line(e)


# -- the tree -------------------------------------------------------------------------------


def test_tree_large_on_smooth_small_on_busy(model):
    smooth = encode_adaptive(material(()), model, (32, 8, 8), progress=False)
    assert smooth.tree.counts() == {4: 4, 2: 0}
    busy = encode_adaptive(material(((0, 0), (0, 1), (1, 0), (1, 1))), model, (32, 8, 8),
                           progress=False)  # fmt: skip
    assert busy.tree.counts()[2] >= 8  # at least half the texture in 2x2 nodes
    for coded in (smooth, busy):  # the τ rule: at most the bytes of the fixed code at 4x4
        a = coded.params["adaptive"]
        assert a["bytes_table4"] <= a["budget_bytes"]


def test_mixed_tree_splits_the_busy_blocks(mixed):
    coded, _ = mixed
    big = {(int(r) // 4, int(c) // 4) for r, c, s in coded.tree.nodes if s == 4}
    assert big == {(0, 0), (1, 1)}
    assert coded.tree.counts() == {4: 2, 2: 8}
    assert coded.params["adaptive"]["bytes_table4"] <= 1500


# -- files ----------------------------------------------------------------------------------


def test_file_round_trip(model, mixed):
    coded, path = mixed
    back = load_coded(path, model, adaptive=True)
    assert isinstance(back, AdaptiveCodedBTF)
    np.testing.assert_array_equal(back.tree.nodes, coded.tree.nodes)
    assert back.params["adaptive"] == coded.params["adaptive"]
    for p in (4, 2):
        for ch in ("Y", "U", "V"):
            a, b = coded.node_codes(p)[ch], back.node_codes(p)[ch]
            np.testing.assert_array_equal(a.counts, b.counts)
            np.testing.assert_array_equal(a.membership, b.membership)
            np.testing.assert_array_equal(a.locations, b.locations)
            np.testing.assert_array_equal(a.values.astype(np.float16), b.values)


def test_fixed_size_readers_refuse_adaptive_files(mixed, model):
    _, path = mixed
    with pytest.raises(FileFormatError) as e:
        load_coded(path)  # what the readers of one patch size read with
    assert "adaptive patch sizes" in _one_line(e)
    with pytest.raises(FileFormatError):
        RuntimeBTF.from_file(path)
    rt = AdaptiveRuntimeBTF(load_coded(path, model, adaptive=True))
    # (its renderer arrays serve the viewer: tests/test_adaptive_arrays.py, test_adaptive_viewer.py)
    wi = np.array([[0.0, 0.0, 1.0]])
    with pytest.raises(BTFInputError) as e:
        rt.evaluate(wi, wi, texel=np.array([[0, 0]]), backend="cuda")
    assert "backend" in _one_line(e)


def _rewrite_nodes(src, dst, nodes: np.ndarray) -> None:
    dst.write_bytes(src.read_bytes())
    with h5py.File(dst, "r+") as f:
        del f["tree/nodes"]
        f["tree"].create_dataset("nodes", data=nodes.astype("<u2"))


@pytest.mark.parametrize(("change", "says"), [
    ("overlap", "overlap"),
    ("missing", "missing"),
    ("outside", "outside"),
    ("off_grid", "not on the"),
    ("size", "not one of the patch sizes"),
])  # fmt: skip
def test_hostile_trees_are_one_line(mixed, tmp_path, change, says):
    coded, path = mixed
    nodes = coded.tree.nodes.copy()
    small = np.flatnonzero(nodes[:, 2] == 2)
    if change == "overlap":
        nodes[small[0], :2] = nodes[small[1], :2]
    elif change == "missing":
        nodes = np.delete(nodes, small[0], axis=0)
    elif change == "outside":
        nodes[small[0], 0] = 8
    elif change == "off_grid":
        nodes[small[0], 0] += 1
    else:
        nodes[small[0], 2] = 3
    bad = tmp_path / "bad.h5"
    _rewrite_nodes(path, bad, nodes)
    with pytest.raises(FileFormatError) as e:
        load_coded(bad, adaptive=True)
    assert says in _one_line(e) and "tree/nodes" in str(e.value)


def test_node_size_the_model_lacks_is_one_line(model, mixed):
    _, path = mixed
    only_small = model.for_patch(2)  # the same hash, one size: 2x2
    with pytest.raises(SparseBTFError) as e:
        load_coded(path, only_small, adaptive=True)
    assert "nodes of size 4" in _one_line(e)


def test_tree_checks_in_memory():
    with pytest.raises(BTFInputError) as e:
        PatchTree.from_nodes(8, 8, (4, 2), np.array([[0, 0, 4], [4, 0, 4], [0, 4, 4]]))
    assert "missing" in _one_line(e)


# -- decoders against the reference ---------------------------------------------------------


def _reference(coded: AdaptiveCodedBTF) -> np.ndarray:
    """Every node decoded on its own (Eq. 4 on its size's dictionaries), then the
    preprocessing undone: (8, 8, 13, 13, 3) linear RGB."""
    model = coded.model
    z = np.zeros((coded.height, coded.width, len(coded.lights), len(coded.views), 3))
    for r, c, s in coded.tree.nodes:
        layer = coded.layers[int(s)]
        point = int(r // s + (coded.height // s) * (c // s))
        for i, ch in enumerate(("Y", "U", "V")):
            x = reconstruct_points(layer.codes[ch], model.for_patch(int(s)).dictionaries[ch],
                                   [point])[0]  # fmt: skip
            z[r:r + s, c:c + s, :, :, i] = x
    pre = Preprocessor(coded.stats)
    return pre.inverse(z, np.arange(z.shape[2]), np.arange(z.shape[3]))


def test_dense_decode_matches_the_reference(model, mixed):
    _, path = mixed
    coded = load_coded(path, model, adaptive=True)
    ref = _reference(coded)
    got = decoded_view(coded).to_array()
    np.testing.assert_allclose(got, ref, rtol=2e-4, atol=1e-6)
    # a read across node borders of both sizes: rows 2..5, columns 3..4, two directions
    part = decoded_view(coded).read(slice(2, 6), [3, 4], [0, 5], [7])
    np.testing.assert_allclose(part, ref[2:6][:, [3, 4]][:, :, [0, 5]][:, :, :, [7]],
                               rtol=2e-4, atol=1e-6)  # fmt: skip


def test_evaluate_matches_the_reference(model, mixed):
    _, path = mixed
    coded = load_coded(path, model, adaptive=True)
    ref = _reference(coded)
    rt = AdaptiveRuntimeBTF(coded)
    # texels in 4x4 nodes, in 2x2 nodes, and on both sides of every border between them
    texels = np.array([[0, 0], [3, 3], [3, 4], [4, 3], [4, 4], [1, 6], [6, 1], [7, 7], [5, 2]])
    li = np.array([0, 3, 5, 7, 12, 1, 2, 9, 4])
    vi = np.array([1, 5, 0, 7, 2, 11, 3, 6, 8])
    got = rt.evaluate(coded.lights.xyz[li], coded.views.xyz[vi], texel=texels,
                      interpolation="nearest")  # fmt: skip
    want = ref[texels[:, 0], texels[:, 1], li, vi]
    np.testing.assert_allclose(got, want, rtol=2e-4, atol=1e-6)
    sizes = coded.tree.sizes_at(texels[:, 0], texels[:, 1])
    assert set(sizes.tolist()) == {2, 4}
    uv = (texels[:, ::-1] + 0.5) / 8.0  # the same texels by texture coordinates
    by_uv = rt.evaluate(coded.lights.xyz[li], coded.views.xyz[vi], uv=uv,
                        interpolation="nearest")  # fmt: skip
    np.testing.assert_array_equal(by_uv, got)
    rt_file = AdaptiveRuntimeBTF.from_file(path)  # its model from the file it recorded
    assert rt_file.meta["patch_sizes"] == [4, 2]
    np.testing.assert_array_equal(rt_file.evaluate(coded.lights.xyz[li], coded.views.xyz[vi],
                                                   texel=texels, interpolation="nearest"), got)


@pytest.mark.skipif(not HAVE_NUMBA, reason="numba is not installed")
def test_numba_backend_matches_the_numpy_reference(model, mixed, monkeypatch):
    """The numba kernels of each layer against the NumPy path, at texels in nodes of both
    sizes and on both sides of every border, at directions between the measured ones (the
    angular interpolation of both domains) and with a fractional per-query τ."""
    _, path = mixed
    coded = load_coded(path, model, adaptive=True)
    rt = AdaptiveRuntimeBTF(coded)
    texels = np.array([[0, 0], [3, 3], [3, 4], [4, 3], [4, 4], [1, 6], [6, 1], [7, 7], [5, 2],
                       [2, 5], [4, 7], [7, 4]])  # fmt: skip
    n = texels.shape[0]
    assert set(coded.tree.sizes_at(texels[:, 0], texels[:, 1]).tolist()) == {2, 4}
    rng = np.random.default_rng(5)
    wi, wo = (rng.normal(size=(n, 3)) for _ in range(2))
    wi[:, 2], wo[:, 2] = np.abs(wi[:, 2]) + 0.2, np.abs(wo[:, 2]) + 0.2
    wi /= np.linalg.norm(wi, axis=1, keepdims=True)
    wo /= np.linalg.norm(wo, axis=1, keepdims=True)
    frac = rng.uniform(0.5, 3.5, size=n)  # below every node's stored count: the prefix fades
    from sparsebtf.runtime import kernels, wavefront

    used = []  # the backend each layer's kernels ran on (the numba answer is not NumPy's)
    for fn in ("separable_sum", "pair_sums"):
        real = getattr(kernels, fn)
        monkeypatch.setattr(kernels, fn, lambda *a, _f=real: (used.append(a[-1]), _f(*a))[1])
    real_sums = wavefront.separable_sums  # the compiled loops (numba only)
    monkeypatch.setattr(wavefront, "separable_sums",
                        lambda *a, **k: (used.append("numba"), real_sums(*a, **k))[1])
    for kwargs in ({"interpolation": "linear"}, {"interpolation": "gaussian", "domain": "log"},
                   {"interpolation": "barycentric", "tau": frac}):  # fmt: skip
        ref = rt.evaluate(wi, wo, texel=texels, backend="numpy", **kwargs)
        used.clear()
        got = rt.evaluate(wi, wo, texel=texels, backend="numba", **kwargs)
        assert used and set(used) == {"numba"}
        # float32 dictionaries and values, sums in another order: rounding only
        np.testing.assert_allclose(got, ref, rtol=1e-5, atol=1e-7)
    # nearest at measured directions is the dense reference itself
    li, vi = np.arange(n) % 13, (3 * np.arange(n)) % 13
    got = rt.evaluate(coded.lights.xyz[li], coded.views.xyz[vi], texel=texels,
                      interpolation="nearest", backend="numba")  # fmt: skip
    np.testing.assert_allclose(got, _reference(coded)[texels[:, 0], texels[:, 1], li, vi],
                               rtol=2e-4, atol=1e-6)  # fmt: skip


def test_library_decode_of_an_adaptive_file(model, mixed):
    import sparsebtf as sb

    _, path = mixed
    decoded = sb.decode(path, model=model)
    assert isinstance(load_coded_with_model(path, adaptive=True), AdaptiveCodedBTF)
    ref = _reference(load_coded(path, model, adaptive=True))
    np.testing.assert_allclose(decoded.angular_image(3, 4), ref[:, :, 3, 4], rtol=2e-4,
                               atol=1e-6)  # fmt: skip


def test_docs_reader_reads_an_adaptive_file(model, mixed, tmp_path):
    """docs/format.md's schema-3 and schema-4 blocks, run where sparsebtf cannot be imported,
    give the tree and each size's codes load_coded gives."""
    import re
    import subprocess
    import sys
    from pathlib import Path

    _, path = mixed
    text = (Path(__file__).resolve().parents[1] / "docs" / "format.md").read_text()
    blocks = [re.search(rf"<!-- schema{v}-reader -->\s*```python\n(.*?)```", text, re.S)
              for v in (3, 4)]  # fmt: skip
    assert all(blocks), "docs/format.md lost a reader block"
    out = tmp_path / "out.npz"
    script = (
        "import sys\nsys.modules['sparsebtf'] = None  # any import of it fails\n"
        + blocks[0].group(1) + blocks[1].group(1)
        + "\nnodes, codes = read_coded_v4(sys.argv[1])\n"
        "flat = {f'{p}/{ch}/{k}': v for p, c in codes.items() for ch, cc in c.items()"
        " for k, v in cc.items()}\n"
        "s, off, k, vals, locs = texel_node(nodes, codes, 5, 2, 'U')\n"
        "np.savez(sys.argv[2], nodes=nodes, size=s, off=off, k=k, vals=vals, locs=locs, **flat)\n"
    )
    r = subprocess.run([sys.executable, "-c", script, str(path), str(out)],
                       capture_output=True, text=True, timeout=120)  # fmt: skip
    assert r.returncode == 0, r.stderr
    got = np.load(out)
    back = load_coded(path, model, adaptive=True)
    np.testing.assert_array_equal(got["nodes"], back.tree.nodes)
    for p in (4, 2):
        for ch, c in back.node_codes(p).items():
            np.testing.assert_array_equal(got[f"{p}/{ch}/counts"], c.counts)
            np.testing.assert_array_equal(got[f"{p}/{ch}/locations"], c.locations)
            np.testing.assert_array_equal(got[f"{p}/{ch}/values"].astype(np.float32), c.values)
    # texel (5, 2) lies in the 2x2 node at (4, 2): point 2 + 4·1 = 6 of the 2x2 grid
    assert int(got["size"]) == 2 and got["off"].tolist() == [1, 0]
    layer = back.layers[2].codes["U"]
    loc, val = layer.point(6)
    assert int(got["k"]) == int(layer.membership[6])
    np.testing.assert_array_equal(got["locs"], loc)
    np.testing.assert_array_equal(got["vals"].astype(np.float32), val)


def test_library_option_and_refusals(model):
    import sparsebtf as sb
    from sparsebtf.codec import encode as encode_fixed

    btf = material(())
    coded = sb.encode(btf, model, target=(32, 8, 8), adaptive_patches=True, progress=False)
    assert isinstance(coded, AdaptiveCodedBTF) and coded.tree.counts() == {4: 4, 2: 0}
    with pytest.raises(BTFInputError) as e:
        encode_fixed(btf, model, (32, 8, 8), adaptive_patches=True, progress=False)
    assert "adaptive_patches" in _one_line(e)
    with pytest.raises(BTFInputError) as e:
        sb.encode(btf, model, target="2000B", adaptive_patches=True, budget="stored")
    assert "Table 4" in _one_line(e)


def test_cli_encode_info_lookup(model, mixed, tmp_path, capsys, monkeypatch):
    import json

    import sparsebtf as sb
    from sparsebtf.cli.main import main

    monkeypatch.chdir(tmp_path)
    sb.save_btf(material(MIXED), "mixed.h5")
    save_model(model, "model.h5")
    assert main(["encode", "mixed.h5", "-m", "model.h5", "-o", "m.coded.h5",
                 "--adaptive-patches", "--target-size", "1500", "--budget", "paper"]) == 0
    capsys.readouterr()
    assert main(["info", "m.coded.h5", "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["schema_version"] == 4
    assert info["tree"]["nodes"] == {"4x4": 2, "2x2": 8}
    assert main(["lookup", "m.coded.h5", "--texel", "5,2", "--light", "3", "--view", "4",
                 "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["node_size"] == 2
    want = decoded_view(load_coded("m.coded.h5", model, adaptive=True)).read([5], [2], [3], [4])
    np.testing.assert_allclose(out["rgb"], want[0, 0, 0, 0], rtol=1e-5)
    assert main(["encode", "mixed.h5", "-m", "model.h5", "-o", "x.h5", "--adaptive-patches",
                 "--target-size", "1500", "--budget", "stored"]) == 2
    assert len(capsys.readouterr().err.strip().splitlines()) == 1


def test_fixed_size_decoders_refuse_an_adaptive_material(model, mixed):
    from sparsebtf.runtime import DecodedBTF

    coded = load_coded(mixed[1], model, adaptive=True)
    for make in (lambda: RuntimeBTF(coded), lambda: DecodedBTF(coded)):
        with pytest.raises(BTFInputError) as e:
            make()
        assert "adaptive patch sizes" in _one_line(e)


# -- blending materials with different trees ------------------------------------------------

FULL = 4 * 4 * 13 * 13  # every coefficient of a 4x4 point: no node is re-sparsified


@pytest.fixture(scope="module")
def other(model):
    """A material busy in block (0, 0) only: its tree differs from the mixed one's."""
    return encode_adaptive(material(((0, 0),), seed=11), model, (64, 16, 16),
                           target_bytes=1500, progress=False)  # fmt: skip


def test_blend_of_different_trees_equals_the_blend_of_decoded_values(model, mixed, other):
    """On the common refinement of the trees, each coarse node re-expressed at the finer
    size: before re-sparsification the blend's standardised values are the α-blend of the
    inputs' standardised decoded values (the domain blending works in, as Eq. 7)."""
    from sparsebtf.runtime import blend
    from sparsebtf.runtime.blend_adaptive import union_tree

    a = load_coded(mixed[1], model, adaptive=True)
    b = other
    sa, sb = a.tree.size_map(), b.tree.size_map()
    assert ((sa > sb).any() and (sb > sa).any()), "each tree must be coarser somewhere"
    out = blend([a, b], alpha=0.3, tau=FULL, progress=False)
    assert isinstance(out, AdaptiveCodedBTF)
    np.testing.assert_array_equal(out.tree.size_map(), np.minimum(sa, sb))
    assert out.tree.n_nodes == union_tree([a.tree, b.tree]).n_nodes
    everything = (slice(None),) * 4
    za, zb, zo = (decoded_view(c).read_standardised(*everything) for c in (a, b, out))
    # float32 coefficients through four change-of-basis products: rounding, ~1e-6 of values
    # of order 1 (a dropped or misplaced sub-block would be off by the values themselves)
    np.testing.assert_allclose(zo, 0.7 * za + 0.3 * zb, atol=2e-5)
    for ch in out.channels:  # nothing dropped but rounding
        assert all(np.all(layer.codes[ch].errors < 1e-12) for layer in out.layers.values())
    # re-sparsified to the default caps: every node within its size's cap, errors recorded
    cut = blend([a, b], alpha=0.3, progress=False)
    np.testing.assert_array_equal(cut.tree.nodes, out.tree.nodes)
    for p, layer in cut.layers.items():
        cap = -(-64 * p * p // 16)  # ⌈τ·(p/4)²⌉ on Y at τ = 64
        assert layer.codes["Y"].counts.max() <= cap
    # a weight of zero does not refine the tree: α = 0 is the first input, tree and codes
    same = blend([a, b], alpha=0.0, progress=False)
    np.testing.assert_array_equal(same.tree.nodes, a.tree.nodes)
    for p in a.tree.sizes:
        for ch in a.channels:
            x, y = a.node_codes(p)[ch], same.node_codes(p)[ch]
            np.testing.assert_array_equal(x.counts, y.counts)
            np.testing.assert_array_equal(x.values, y.values)


def test_blend_of_adaptive_materials_saves_and_refuses_a_mix(model, mixed, other, tmp_path):
    from sparsebtf.runtime import blend

    a = load_coded(mixed[1], model, adaptive=True)
    out = blend([a, other], weights=[0.5, 0.5], progress=False)
    path = save_coded(out, tmp_path / "blend.coded.h5")
    back = load_coded(path, model, adaptive=True)
    np.testing.assert_array_equal(back.tree.nodes, out.tree.nodes)
    assert back.params["blend"]["weights"] == [0.5, 0.5] and "adaptive" not in back.params
    fixed = a.layers[4]  # a fixed-size coded BTF of the same model
    with pytest.raises(BTFInputError) as e:
        blend([fixed, a], alpha=0.5)
    assert "coded one way" in _one_line(e)


def test_resumed_encode_reads_its_ranges_back(model, tmp_path, monkeypatch):
    from sparsebtf.codec.adaptive import AdaptivePlan
    from sparsebtf.codec.options import EncodeOptions

    btf = material(MIXED)
    opts = EncodeOptions(checkpoint_dir=tmp_path / "ck", progress=False)
    first = encode_adaptive(btf, model, (64, 16, 16), target_bytes=1500, options=opts)
    assert list((tmp_path / "ck").iterdir())  # the ranges were saved

    def no_coding(*args, **kwargs):
        raise AssertionError("a saved range was coded again")

    monkeypatch.setattr(AdaptivePlan, "code_range", no_coding)
    again = encode_adaptive(btf, model, (64, 16, 16), target_bytes=1500, options=opts)
    np.testing.assert_array_equal(again.tree.nodes, first.tree.nodes)
    for p in (4, 2):
        for ch, c in first.node_codes(p).items():
            np.testing.assert_array_equal(again.node_codes(p)[ch].values, c.values)


def test_model_file_with_a_wrong_size_list_is_one_line(model, tmp_path):
    path = save_model(model, tmp_path / "m.h5")
    with h5py.File(path, "r+") as f:
        del f.attrs["patch_sizes"]
        f.attrs["patch_sizes"] = np.bytes_(b"[4, 1]")
    with pytest.raises(FileFormatError) as e:
        load_model(path)
    assert "patches" in _one_line(e)


def test_cli_blend_of_adaptive_files(model, mixed, other, tmp_path, capsys):
    import json

    from sparsebtf.cli.main import main
    from sparsebtf.runtime import blend

    save_model(model, tmp_path / "model.h5")
    b = save_coded(other, tmp_path / "other.coded.h5")
    out = tmp_path / "mix.coded.h5"
    assert main(["blend", str(mixed[1]), str(b), "--alpha", "0.3", "-o", str(out), "-m",
                 str(tmp_path / "model.h5"), "--sweep", "2", "--png", str(tmp_path / "strip"),
                 "--json"]) == 0  # fmt: skip
    report = json.loads(capsys.readouterr().out)
    assert len(report["sweep"]) == 2
    back = load_coded(out, model, adaptive=True)
    want = blend([load_coded(mixed[1], model, adaptive=True), load_coded(b, model, adaptive=True)],
                 alpha=0.3, progress=False)  # fmt: skip
    np.testing.assert_array_equal(back.tree.nodes, want.tree.nodes)
    # the sweep's α = 0 render is the first material's image at the Figure 6 directions
    from sparsebtf.cli.blend import FIGURE6_LIGHT, FIGURE6_VIEW, direction

    rt = AdaptiveRuntimeBTF(load_coded(mixed[1], model, adaptive=True))
    img = rt.image(direction(FIGURE6_LIGHT, "l"), direction(FIGURE6_VIEW, "v"))
    assert img.shape == (8, 8, 3)
    np.testing.assert_allclose(report["sweep"][0]["mean_rgb"], img.reshape(-1, 3).mean(axis=0),
                               rtol=1e-5)  # fmt: skip

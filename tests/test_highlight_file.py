"""The highlight store's files (issue 46): schemas 5 to 8 written and read back, their bytes
as counted, and every damaged field refused in one line."""

from __future__ import annotations

from dataclasses import replace

import h5py
import numpy as np
import pytest

from sparsebtf.codec import encode
from sparsebtf.errors import BTFInputError, FileFormatError
from sparsebtf.learning.entry_code import HEADER_BYTES, TINT_BYTES, quantise
from sparsebtf.learning.highlights import POINT_BYTES, Highlights, entry_bytes
from sparsebtf.learning.lobes import LOBE_BYTES
from sparsebtf.runtime import RuntimeBTF
from sparsebtf.runtime.dense import DecodedBTF
from sparsebtf.storage import load_coded, save_coded, storage_report
from sparsebtf.storage.highlight_file import (
    COMPACT_SCHEMA,
    HIGHLIGHT_SCHEMA,
    LOBE_SCHEMA,
    TINT_SCHEMA,
)

from .conftest import smooth_btf, tiny_model
from .test_highlight_decode import random_store


@pytest.fixture(scope="module")
def model():
    return tiny_model(max_iter=2)


def untinted(c):
    """``c`` with its tinted store's corrections as an untinted compact store (schema 7)."""
    h = c.highlights
    pts = np.repeat(np.arange(h.n_points), np.diff(h.offsets))
    return replace(c, highlights=replace(Highlights.from_nodes(pts, h.keys, quantise(h.rgb),
                                                               h.n_points), lobes=h.lobes))


def test_file_round_trip_tinted_schema_8(tinted_level, tmp_path, model):
    c = tinted_level
    h = c.highlights
    assert h.compact and h.tints is not None
    path = save_coded(c, tmp_path / "g.h5")
    with h5py.File(path) as f:
        assert int(f.attrs["schema_version"]) == TINT_SCHEMA
        g = f["highlights"]
        assert "keys" not in g and "rgb8" not in g and g["scale8"].shape == (h.n_entries,)
        assert g["tints"].shape == (c.n_points, 3)
        streams = g["unary"].size + g["remainder"].size
    back = load_coded(path, model)
    for name in ("offsets", "keys", "rgb", "tints", "scales"):
        np.testing.assert_array_equal(getattr(back.highlights, name), getattr(h, name))
    a = np.asarray(DecodedBTF(back).to_array())
    b = np.asarray(DecodedBTF(c).to_array())
    np.testing.assert_allclose(a, b, rtol=2e-3, atol=2e-3)
    # the runtime reads the loaded store: at sampled directions, the dense decode
    rng = np.random.default_rng(1)
    texel = rng.integers(0, c.height, (200, 2))
    li, vi = rng.integers(0, len(c.lights), 200), rng.integers(0, len(c.views), 200)
    got = RuntimeBTF(back).evaluate(c.lights.xyz[li], c.views.xyz[vi], texel=texel,
                                    interpolation="nearest")  # fmt: skip
    np.testing.assert_allclose(got, a[texel[:, 0], texel[:, 1], li, vi], rtol=2e-5, atol=2e-5)
    # the counted bytes are the code's: the two streams as written, an E5M2 byte an entry, a
    # binary16 tint a point (and the lobes' 16 bytes a texel)
    rep = storage_report(back, model, path)
    lobes = 0 if h.lobes is None else h.lobes.shape[0] * h.lobes.shape[1] * LOBE_BYTES
    assert rep["bytes_highlights"] == (streams + h.n_entries + TINT_BYTES * c.n_points
                                       + HEADER_BYTES + lobes)  # fmt: skip


def test_file_round_trip_compact_schema_7(levels, tmp_path, model):
    c = untinted(levels[-1])
    h = c.highlights
    assert h.compact and h.tints is None
    path = save_coded(c, tmp_path / "g.h5")
    with h5py.File(path) as f:
        assert int(f.attrs["schema_version"]) == COMPACT_SCHEMA
        assert "keys" not in f["highlights"] and f["highlights/rgb8"].dtype == np.uint8
    back = load_coded(path, model)
    for name in ("offsets", "keys", "rgb"):
        np.testing.assert_array_equal(getattr(back.highlights, name), getattr(h, name))
    assert back.highlights.tints is None
    # the counted bytes are the code's: the two streams as written, an E5M2 byte a channel
    with h5py.File(path) as f:
        streams = f["highlights/unary"].size + f["highlights/remainder"].size
    rep = storage_report(back, model, path)
    lobes = 0 if h.lobes is None else h.lobes.shape[0] * h.lobes.shape[1] * LOBE_BYTES
    assert rep["bytes_highlights"] == streams + 3 * h.n_entries + HEADER_BYTES + lobes
    assert rep["bytes_highlights"] < h.n_entries * entry_bytes(c.patch, len(c.lights),
                                                               len(c.views))  # fmt: skip


def test_info_shows_the_store(levels, tinted_level, tmp_path, model, capsys):
    import json

    from sparsebtf.cli.main import main
    from sparsebtf.storage import save_model

    mf = tmp_path / "m.h5"
    save_model(model, mf)
    for c, code in ((levels[-1], "compact: 8-bit"), (tinted_level, "compact, tinted")):
        path = save_coded(c, tmp_path / "g.h5")
        assert main(["info", str(path), "--model", str(mf), "--json"]) == 0
        got = json.loads(capsys.readouterr().out)["highlights"]
        assert got["entries"] == c.highlights.n_entries and got["code"].startswith(code)
        assert got["bytes_table4"] == storage_report(c, model)["bytes_highlights"]


def test_file_round_trip_schema_5(levels, tmp_path, model):
    """A store with binary16 corrections off the E5M2 grid is written exactly (schema 5) and
    counted as Table 4 counts a coefficient."""
    c = replace(levels[-1], highlights=random_store(levels[-1], share=0.05))
    assert not c.highlights.compact
    path = save_coded(c, tmp_path / "g.h5")
    with h5py.File(path) as f:
        assert int(f.attrs["schema_version"]) == HIGHLIGHT_SCHEMA
    back = load_coded(path, model)
    for name in ("offsets", "keys", "rgb"):
        np.testing.assert_array_equal(getattr(back.highlights, name), getattr(c.highlights, name))
    rep = storage_report(back, model, path)
    h = c.highlights
    # an entry as Table 4 counts a coefficient: a location (3 bytes below 2^24 nodes) and
    # three binary16 values
    per = 3 + 3 * 2 if c.patch**2 * len(c.lights) * len(c.views) <= 1 << 24 else 4 + 3 * 2
    assert entry_bytes(c.patch, len(c.lights), len(c.views)) == per
    assert rep["bytes_highlights"] == h.n_entries * per + h.n_points * POINT_BYTES
    assert entry_bytes(10, 151, 151) == 9 and entry_bytes(64, 151, 151) == 10
    assert rep["bytes_stored_codes"] > 0


def test_lobes_file_round_trip_schema_6(lobed, model, tmp_path):
    path = save_coded(lobed, tmp_path / "l.h5")
    with h5py.File(path) as f:
        assert int(f.attrs["schema_version"]) == LOBE_SCHEMA
        assert f["highlights/lobes"].shape == (lobed.n_points, 16, 8)
    back = load_coded(path, model)
    np.testing.assert_array_equal(back.highlights.lobes, lobed.highlights.lobes)
    a = np.asarray(DecodedBTF(back).to_array())
    b = np.asarray(DecodedBTF(lobed).to_array())
    np.testing.assert_allclose(a, b, rtol=2e-3, atol=2e-3)
    h = lobed.highlights
    assert storage_report(back, model, path)["bytes_highlights"] == (
        h.n_entries * entry_bytes(4, 13, 13) + h.n_points * POINT_BYTES
        + h.n_points * 16 * LOBE_BYTES)


@pytest.mark.parametrize("damage, message", [
    ("negative", "negative amplitude"), ("nan", "not finite"), ("shape", "lobes"),
    ("in schema 5", "schema 6 holds them"),
])  # fmt: skip
def test_damaged_lobes_are_one_line(lobed, model, tmp_path, damage, message):
    path = save_coded(lobed, tmp_path / "d.h5")
    with h5py.File(path, "r+") as f:
        g = f["highlights"]
        lobes = g["lobes"][()]
        if damage == "negative":
            lobes[1, 2, 6] = -1
        elif damage == "nan":
            lobes[0, 3, 0] = np.nan
        elif damage == "shape":
            lobes = lobes[:, :8]
        else:
            f.attrs["schema_version"] = HIGHLIGHT_SCHEMA
        _rewrite(g, "lobes", lobes)
    with pytest.raises(FileFormatError, match=message) as e:
        load_coded(path, model)
    assert "\n" not in str(e.value)


def test_no_store_stays_schema_3(model, tmp_path):
    c = encode(smooth_btf(5), model, tau=(32, 8, 8), eps=0.0, progress=False)
    with h5py.File(save_coded(c, tmp_path / "p.h5")) as f:
        assert int(f.attrs["schema_version"]) == 3
        assert "highlights" not in f


def test_schema_2_cannot_hold_a_store(levels, tmp_path):
    assert levels[0].highlights.tints is None  # three E5M2 values an entry: schema 7
    with pytest.raises(BTFInputError, match=f"written in schema {COMPACT_SCHEMA}"):
        save_coded(levels[0], tmp_path / "x.h5", schema=2)


def _rewrite(g, name, data):
    """Replace dataset ``name`` of group ``g`` (no checksum kept: the damage is the point)."""
    del g[name]
    g.create_dataset(name, data=data)


def _key_past_the_nodes(g, limit):
    # the first gap as long as the material's `limit` nodes (the remainder's bits all ones),
    # the rest 0
    n, k = int(g.attrs["n_entries"]), int(g.attrs["rice_k"])
    bits = np.concatenate([np.ones(limit >> k, np.uint8), np.zeros(n, np.uint8)])
    _rewrite(g, "unary", np.packbits(np.concatenate([bits, np.ones(-bits.size % 8, np.uint8)])))
    _rewrite(g, "remainder", np.full(-(-n * k // 8), 255, np.uint8))


@pytest.mark.parametrize("damage, message", [
    (lambda g: _rewrite(g, "keys", np.full(g["keys"].shape, 2**31, np.uint32)), "outside"),
    (lambda g: g.attrs.__setitem__("n_entries", int(g.attrs["n_entries"]) + 1), "sums to"),
    (lambda g: g.attrs.__setitem__("space", "log"), "space"),
])  # fmt: skip
def test_damaged_store_is_one_line(levels, tmp_path, model, damage, message):
    c = replace(levels[-1], highlights=random_store(levels[-1], share=0.05))
    path = save_coded(c, tmp_path / "d.h5")
    with h5py.File(path, "r+") as f:
        damage(f["highlights"])
    with pytest.raises(FileFormatError, match=message) as e:
        load_coded(path, model)
    assert "\n" not in str(e.value)


@pytest.mark.parametrize("tinted, damage, message", [
    (True, lambda g, _: g.attrs.__setitem__("n_entries", int(g.attrs["n_entries"]) + 1),
     "remainder|closes"),
    (True, lambda g, _: _rewrite(g, "unary", np.concatenate([g["unary"][()], [255]])), "unary"),
    (True, lambda g, _: _rewrite(g, "unary", np.zeros_like(g["unary"][()])), "closes"),
    (True, _key_past_the_nodes, "past the"),
    (True, lambda g, _: g.attrs.__setitem__("rice_k", 99), "rice_k"),
    (True, lambda g, _: _rewrite(g, "scale8", np.full(g["scale8"].shape, 0x7C, np.uint8)),
     "scale8: entry 0 is not finite"),
    (True, lambda g, _: _rewrite(g, "scale8", g["scale8"][()].astype(np.uint16)), "uint8"),
    (True, lambda g, _: _rewrite(g, "tints", np.full(g["tints"].shape, np.inf, np.float16)),
     "tints: the tint of point 0"),
    (True, lambda g, _: _rewrite(g, "tints", g["tints"][:-1]), "tints"),
    (True, lambda g, _: _rewrite(g, "scale8", g["scale8"][:-1]), "scale8"),
    (False, lambda g, _: _rewrite(g, "rgb8", np.full(g["rgb8"].shape, 0x7C, np.uint8)),
     "rgb8: entry 0 is not finite"),
    (False, lambda g, _: _rewrite(g, "rgb8", g["rgb8"][()].astype(np.uint16)), "uint8"),
    (False, _key_past_the_nodes, "past the"),
])  # fmt: skip
def test_damaged_compact_store_is_one_line(levels, tinted_level, tmp_path, model, tinted,
                                           damage, message):  # fmt: skip
    """``damage(group, nodes of the material)`` on a saved compact store, tinted (schema 8)
    or not (7)."""
    c = tinted_level if tinted else untinted(levels[-1])
    path = save_coded(c, tmp_path / "d.h5")
    with h5py.File(path, "r+") as f:
        damage(f["highlights"], c.n_points * c.patch**2 * len(c.lights) * len(c.views))
    with pytest.raises(FileFormatError, match=message) as e:
        load_coded(path, model)
    assert "\n" not in str(e.value)


def test_keys_must_rise_within_a_point(levels):
    h = levels[-1].highlights
    bad = Highlights(h.offsets, h.keys[::-1].copy(), h.rgb)
    with pytest.raises(BTFInputError, match="increase"):
        bad.check(levels[-1].n_points, 4, 13, 13, "test")



"""The highlight store (issue 46): the encoder's choice of base code and entries within each
level's bytes, the schema-5 file, the dense decoder and the byte accounting."""

from __future__ import annotations

import itertools
from dataclasses import replace

import h5py
import numpy as np
import pytest

from sparsebtf.codec import encode, encode_levels
from sparsebtf.codec.highlights import base_taus, choose_highlights
from sparsebtf.data.btf import ArrayBTF
from sparsebtf.errors import BTFInputError, FileFormatError
from sparsebtf.learning.entry_code import HEADER_BYTES, TINT_BYTES, quantise
from sparsebtf.learning.highlights import POINT_BYTES, Highlights, entry_bytes, node_keys
from sparsebtf.learning.lobes import LOBE_BYTES, lobe_values
from sparsebtf.runtime import RuntimeBTF
from sparsebtf.runtime.dense import DecodedBTF
from sparsebtf.storage import load_coded, save_coded, storage_report
from sparsebtf.storage.accounting import paper_storage
from sparsebtf.storage.highlight_file import (
    COMPACT_SCHEMA,
    HIGHLIGHT_SCHEMA,
    LOBE_SCHEMA,
    TINT_SCHEMA,
)

from .conftest import smooth_btf, tiny_model
from .test_highlight_decode import random_store

LEVELS = [(16, 4, 4), (32, 8, 8), (64, 16, 16)]


@pytest.fixture(scope="module")
def model():
    return tiny_model(max_iter=2)


def glossy_btf(seed: int = 3) -> ArrayBTF:
    """``smooth_btf`` with sharp highlights: a few (texel, light, view) values × 40–200, the
    kind a log-domain code reaches slowly."""
    b = smooth_btf(seed)
    data = np.array(b.to_array())
    rng = np.random.default_rng(seed)
    hit = rng.random(data.shape[:4]) < 0.01
    data[hit] *= rng.uniform(40, 200, (int(hit.sum()), 1)).astype(np.float32)
    return ArrayBTF(data, b.lights, b.views, name="glossy")


@pytest.fixture(scope="module")
def glossy():
    return glossy_btf()


@pytest.fixture(scope="module")
def levels(glossy, model):
    return encode_levels(glossy, model, LEVELS, eps=0.0, highlights=True, progress=False,
                         allow_below_training=True)  # fmt: skip


@pytest.fixture(scope="module")
def tinted_level(model):
    """A level whose store is tinted: the lowest level of ``tinted_btf`` (its highlights share
    one colour)."""
    coded = encode_levels(tinted_btf(), model, LEVELS, eps=0.0, highlights=True,
                          progress=False, allow_below_training=True)  # fmt: skip
    c = next(c for c in coded if c.params["highlights"]["tinted"])
    assert c.highlights.tints is not None
    return c


def coded_with_bases(btf, model) -> tuple[np.ndarray, list, list]:
    """The reference values of ``btf``, its codes at ``LEVELS`` and at the bases below them
    (one pass), as :func:`choose_highlights` takes them."""
    taus = [dict(zip("YUV", t, strict=True)) for t in LEVELS]
    coded = encode_levels(btf, model, taus + base_taus(taus), eps=0.0, progress=False,
                          allow_below_training=True)  # fmt: skip
    return np.asarray(btf.to_array(), np.float64), coded[: len(LEVELS)], coded[len(LEVELS):]


def sse(coded, ref: np.ndarray) -> float:
    return float(np.square(np.asarray(DecodedBTF(coded).to_array(), np.float64) - ref).sum())


# ---------------------------------------------------------------------------- the encoder


def test_store_pays_on_highlights_and_levels_are_nested(levels, glossy, model):
    ref = np.asarray(glossy.to_array(), np.float64)
    plain = encode_levels(glossy, model, LEVELS, eps=0.0, progress=False,
                          allow_below_training=True)  # fmt: skip
    errs = []
    for lv, p in zip(levels, plain, strict=True):
        rec = lv.params["highlights"]
        got = sse(lv, ref)
        # the error the choice was judged by is the decoders' (binary16 values, clamp: <=)
        assert got <= rec["sse"] * (1 + 1e-5) + 1e-6
        assert got == pytest.approx(rec["sse"], rel=1e-3)
        # within the level's own bytes, and never worse than the level's codes alone
        nbytes = storage_report(lv, model, stored=False)["bytes_table4_material"]
        assert nbytes <= rec["budget_bytes"]
        # the budget: τ coefficients in every point (Table 4), what the plain codes stay within
        assert rec["budget_bytes"] == paper_storage(
            8, 8, 13, 13, 4, rec["level_tau"], 3)["bytes_table4_material"]
        assert storage_report(p, model, stored=False)["bytes_table4_material"] <= rec[
            "budget_bytes"]
        assert got <= sse(p, ref) * (1 + 1e-6)
        errs.append(got)
    assert all(b <= a for a, b in itertools.pairwise(errs))
    # on this material the store pays: every level holds entries and errs clearly less
    assert all(lv.highlights is not None and lv.highlights.n_entries for lv in levels)
    assert errs[0] < 0.8 * sse(plain[0], ref)


def tinted_btf(seed: int = 4) -> ArrayBTF:
    """``smooth_btf`` with copper highlights: at a few (texel, light, view) nodes, 5–50 times
    one colour added (a metal's highlight takes the metal's colour)."""
    b = smooth_btf(seed)
    data = np.array(b.to_array())
    rng = np.random.default_rng(seed)
    hit = rng.random(data.shape[:4]) < 0.02
    amp = rng.uniform(5, 50, (int(hit.sum()), 1))
    data[hit] += (amp * np.array([0.95, 0.64, 0.54])).astype(np.float32)
    return ArrayBTF(data, b.lights, b.views, name="copper")


def test_tinted_entries_buy_more_on_one_colour_highlights(model):
    """One byte an entry instead of three: where the highlights share a colour the tinted
    store holds more entries at a level's bytes and errs less; a level takes whichever kind
    errs less, so allowing tints never costs error; the judged error is the decoders'."""
    btf = tinted_btf()
    ref, plain, bases = coded_with_bases(btf, model)
    both = choose_highlights(btf, plain, bases, model, progress=False, lobes=False)
    rgb = choose_highlights(btf, plain, bases, model, progress=False, lobes=False, tints=False)
    gains = []
    for b, r in zip(both, rgb, strict=True):
        rec = b.params["highlights"]
        assert rec["tinted"] == (b.highlights.tints is not None)
        assert r.highlights.tints is None and not r.params["highlights"]["tinted"]
        assert sse(b, ref) <= sse(r, ref) * (1 + 1e-6)
        assert sse(b, ref) == pytest.approx(rec["sse"], rel=1e-4)
        for c in (b, r):
            assert (storage_report(c, model, stored=False)["bytes_table4_material"]
                    <= c.params["highlights"]["budget_bytes"])  # fmt: skip
        if rec["tinted"]:
            assert rec["entries"] > r.params["highlights"]["entries"]
            gains.append(sse(r, ref) / sse(b, ref))
    assert gains and max(gains) > 2  # the low levels: far more of the highlight stored


def test_tinted_candidates_past_the_memory_budget_fall_back_with_a_warning(model, monkeypatch):
    """Tinted candidates hold three times the entries: where only they do not fit the memory
    budget, the store is coded with three-value entries and the user told how to allow them."""
    import sparsebtf.codec.highlights as hl

    monkeypatch.setattr(hl, "_candidate_bytes", lambda cap, tinted: 10**12 if tinted else 1)
    btf = tinted_btf()
    with pytest.warns(UserWarning, match="tinted highlight entries need .*SPARSEBTF_MAX_MEMORY_GB"):
        out = encode_levels(btf, model, LEVELS[:1], eps=0.0, highlights="entries",
                            progress=False, allow_below_training=True)  # fmt: skip
    assert not out[0].params["highlights"]["tinted"] and out[0].highlights.tints is None
    assert out[0].highlights.n_entries  # the store is still coded


def test_scores_read_the_store(levels, glossy):
    """``bench quality`` scores a material with a store as its decoders read it (the codes'
    log values alone miss the corrections)."""
    from sparsebtf.evaluation.scoring import score_many

    c = levels[-1]
    ref = np.maximum(np.asarray(glossy.to_array(), np.float64), 0)
    (got,) = score_many(glossy, [DecodedBTF(c)], ssim_images=0, progress=False)
    want = np.square(np.asarray(DecodedBTF(c).to_array(), np.float64) - ref).mean()
    assert got["mse_rgb"] == pytest.approx(want, rel=1e-5)
    assert "mse_std" not in got


def lobe_btf(seed: int = 5) -> ArrayBTF:
    """``smooth_btf`` plus one glossy lobe per texel (random facet, α 0.15–0.4, amplitude
    0.5–2): the highlight a grooved metal puts on every texel."""
    b = smooth_btf(seed)
    rng = np.random.default_rng(seed)
    n = b.height * b.width
    params = np.concatenate([rng.uniform(-0.3, 0.3, (n, 3)),
                             np.log(rng.uniform(0.15, 0.4, (n, 2))),
                             rng.uniform(0.5, 2.0, (n, 3))], axis=1)  # fmt: skip
    wi, wo = b.lights.xyz[:, None, :], b.views.xyz[None, :, :]
    lobe = lobe_values(params[:, None, None, :], wi[None], wo[None])
    data = np.asarray(b.to_array(), np.float64) + lobe.reshape(b.height, b.width, *lobe.shape[1:])
    return ArrayBTF(data.astype(np.float32), b.lights, b.views, name="lobes")


def test_lobes_pay_on_a_lobe_material(model):
    btf = lobe_btf()
    ref, plain, bases = coded_with_bases(btf, model)
    with_lobes = choose_highlights(btf, plain, bases, model, progress=False)
    entries_only = choose_highlights(btf, plain, bases, model, progress=False, lobes=False)
    top, other = with_lobes[-1], entries_only[-1]
    rec = top.params["highlights"]
    assert rec["lobes"] and top.highlights.lobes is not None
    assert top.highlights.lobes.shape == (top.n_points, 16, 8)
    got = sse(top, ref)
    assert got == pytest.approx(rec["sse"], rel=1e-3)
    # within the level's bytes, the lobes counted (16 bytes a texel), and far below entries
    rep = storage_report(top, model, stored=False)
    assert rep["bytes_table4_material"] <= rec["budget_bytes"]
    assert rep["bytes_highlights"] >= 64 * LOBE_BYTES
    assert got < 0.5 * sse(other, ref)
    assert not other.params["highlights"]["lobes"]
    errs = [sse(c, ref) for c in with_lobes]
    assert all(b <= a * (1 + 1e-6) for a, b in itertools.pairwise(errs))
    for c in with_lobes:  # every level within its bytes, lobes and counts included
        rep = storage_report(c, model, stored=False)
        assert rep["bytes_table4_material"] <= c.params["highlights"]["budget_bytes"]


def test_entries_only_skips_the_lobes(model, tmp_path, capsys):
    from sparsebtf.api import encode as sb_encode
    from sparsebtf.cli.main import main
    from sparsebtf.storage import save_model

    btf = lobe_btf()
    (lit,) = encode_levels(btf, model, [(64, 16, 16)], eps=0.0, highlights=True, progress=False)
    (bare,) = encode_levels(btf, model, [(64, 16, 16)], eps=0.0, highlights="entries",
                            progress=False)  # fmt: skip
    assert lit.params["highlights"]["lobes"] and lit.highlights.lobes is not None
    assert not bare.params["highlights"]["lobes"] and bare.highlights.lobes is None
    assert sb_encode(btf, model, target=(64, 16, 16), eps=0.0, highlights="lobes",
                     progress=False).highlights.lobes is not None  # fmt: skip
    with pytest.raises(BTFInputError, match="highlights"):
        encode_levels(btf, model, [(64, 16, 16)], highlights="both", progress=False)
    # the command line: --highlights entries writes a store without lobes
    src, mf = tmp_path / "l.h5", tmp_path / "m.h5"
    from sparsebtf.data.dense_file import write_dense

    write_dense(src, btf)
    save_model(model, mf)
    out = tmp_path / "c.h5"
    code = main(["encode", str(src), "--model", str(mf), "--tau", "64,16,16", "--eps", "0",
                 "--highlights", "entries", "-o", str(out)])  # fmt: skip
    capsys.readouterr()
    assert code == 0
    with h5py.File(out) as f:
        assert int(f.attrs["schema_version"]) in (3, TINT_SCHEMA) and "lobes" not in f.get(
            "highlights", {})


def test_no_entries_where_they_do_not_pay(model):
    (c,) = encode_levels(smooth_btf(4), model, [(32, 8, 8)], eps=0.0, highlights=True,
                         progress=False)  # fmt: skip
    rec = c.params["highlights"]
    assert rec["base_tau"]["Y"] <= 32
    if c.highlights is None:
        assert rec["entries"] == 0
    else:
        assert c.highlights.n_entries == rec["entries"]


def test_base_taus_below_the_smallest_level():
    got = base_taus([{"Y": 64, "U": 8, "V": 8}, {"Y": 16, "U": 4, "V": 4}])
    assert got[0] == {"Y": 8, "U": 2, "V": 2}
    assert {"Y": 1, "U": 1, "V": 1} in got
    assert len({tuple(t.values()) for t in got}) == len(got)


def test_highlights_refused_where_not_taken(glossy, model):
    with pytest.raises(BTFInputError, match="highlights"):
        encode(glossy, model, target_ratio=50, highlights=True)


# ---------------------------------------------------------------------------- the file


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


@pytest.fixture(scope="module")
def lobed(model):
    """A coded material whose store has lobes: random ones on the codes of ``smooth_btf(6)``,
    with the first point's entries of a random store."""
    c = encode(smooth_btf(6), model, tau=(32, 8, 8), eps=0.0, progress=False)
    rng = np.random.default_rng(2)
    n = (c.n_points, c.patch**2)
    lobes = np.concatenate([rng.uniform(-0.4, 0.4, (*n, 3)), np.log(rng.uniform(0.1, 0.4, (*n, 2))),
                            rng.uniform(0, 2, (*n, 3))], axis=2).astype(np.float16)  # fmt: skip
    return replace(c, highlights=replace(random_store(c, share=0.1, scale=0.5), lobes=lobes))


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


# ---------------------------------------------------------------------------- the decoders


def test_dense_decode_adds_the_corrections(model):
    c = encode(smooth_btf(6), model, tau=(32, 8, 8), eps=0.0, progress=False)
    h = random_store(c, share=0.2, scale=0.5)
    lit = replace(c, highlights=h)
    plain = np.asarray(DecodedBTF(c).to_array(), np.float64)
    got = np.asarray(DecodedBTF(lit).to_array(), np.float64)
    # every node by hand: its point, its key, its entry (or none)
    p, nl, nv = c.patch, len(c.lights), len(c.views)
    want = plain.copy()
    for pt in range(c.n_points):
        r0, c0 = (pt % (c.height // p)) * p, (pt // (c.height // p)) * p
        lo, hi = h.offsets[pt], h.offsets[pt + 1]
        for key, rgb in zip(h.keys[lo:hi], h.rgb[lo:hi].astype(np.float64), strict=True):
            t, rest = divmod(int(key), nl * nv)
            li, vi = divmod(rest, nv)
            want[r0 + t // p, c0 + t % p, li, vi] += rgb
    np.testing.assert_allclose(got, np.maximum(want, 0), rtol=1e-6, atol=1e-6)
    assert (want < 0).any()  # the clamp is exercised
    # a read of a subset (Eq. 5's sums: float32 rounding apart) is the same subset of the whole
    rows, cols, ls, vs = [1, 6], [7, 0, 3], [2, 11], [0, 5, 12]
    part = DecodedBTF(lit).read(rows, cols, ls, vs)
    np.testing.assert_allclose(part, got[np.ix_(rows, cols, ls, vs)], rtol=1e-5, atol=1e-6)


def test_dense_decode_adds_the_lobes(lobed):
    # lobes alone (no entry): decode + lobe at every node, clamped
    h = replace(Highlights.empty(lobed.n_points), lobes=lobed.highlights.lobes)
    plain = np.asarray(DecodedBTF(replace(lobed, highlights=None)).to_array(), np.float64)
    got = np.asarray(DecodedBTF(replace(lobed, highlights=h)).to_array(), np.float64)
    # by hand: each texel's lobe at every (light, view) pair, from its point and texel index
    p, rb = lobed.patch, lobed.height // lobed.patch
    want = plain.copy()
    dl, dv = lobed.lights.xyz, lobed.views.xyz
    for r in range(lobed.height):
        for c in range(lobed.width):
            prm = h.lobes[r // p + rb * (c // p), (r % p) * p + c % p].astype(np.float64)
            want[r, c] += lobe_values(prm, dl[:, None, :], dv[None, :, :])
    np.testing.assert_allclose(got, np.maximum(want, 0), rtol=1e-5, atol=1e-5)
    assert np.abs(got - plain).max() > 0.1


def test_runtime_at_sampled_directions_equals_dense(model):
    c = encode(smooth_btf(7), model, tau=(32, 8, 8), eps=0.0, progress=False)
    lit = replace(c, highlights=random_store(c, seed=2, share=0.2, scale=0.5))
    dense = np.asarray(DecodedBTF(lit).to_array())
    rt = RuntimeBTF(lit)
    rng = np.random.default_rng(0)
    n = 300
    texel = rng.integers(0, 8, (n, 2))
    li, vi = rng.integers(0, 13, n), rng.integers(0, 13, n)
    got = rt.evaluate(c.lights.xyz[li], c.views.xyz[vi], texel=texel, interpolation="nearest")
    want = dense[texel[:, 0], texel[:, 1], li, vi]
    np.testing.assert_allclose(got, want, rtol=2e-5, atol=2e-5)
    keys = node_keys(texel[:, 0] % 4, texel[:, 1] % 4, li, vi, 4, 13, 13)
    assert keys.max() < 4 * 4 * 13 * 13


def test_blend_and_release_export_refuse_a_store(levels, glossy):
    from sparsebtf.runtime.blend import check_blendable
    from sparsebtf.storage.release_write import check_exportable

    with pytest.raises(BTFInputError, match="highlight store"):
        check_blendable([levels[-1], levels[0]])
    with pytest.raises(BTFInputError, match="highlight store"):
        check_exportable(levels[-1], "0" * 64)


# ---------------------------------------------------------------------------- the benchmark


def test_benchmark_method_codes_within_the_reference_bytes(tmp_path, monkeypatch):
    import json

    from sparsebtf.evaluation.runner import run_quality

    from .test_evaluation import tiny_config

    monkeypatch.setenv("SPARSEBTF_CACHE", str(tmp_path / "cache"))
    cfg = replace(tiny_config(), with_per_channel=False, with_raw=False, with_rate_control=False,
                  pca_domains=("log",), black_materials=())  # fmt: skip
    run_quality(tmp_path / "run", cfg, log=lambda m: None,
                methods=["sparsebtf", "sparsebtf-highlights"])  # fmt: skip
    rows = json.loads((tmp_path / "run" / "results.json").read_text())["rows"]
    ref = {(r["material"], r["level"]): r for r in rows
           if r["method"] == "sparsebtf" and r["set"] == "test" and r["level"] is not None}
    ours = [r for r in rows if r["method"] == "sparsebtf-highlights"]
    assert {(r["material"], r["level"]) for r in ours} == set(ref)
    for r in ours:
        base = ref[(r["material"], r["level"])]
        assert r["material_bytes"] <= base["material_bytes"]
        # the same model (same training), the level's own codes among the candidates
        assert r["mse_rgb"] <= base["mse_rgb"] * (1 + 1e-4)
        assert r["highlight_entries"] >= 0


def test_renderer_arrays_carry_the_store_and_step_6_by_hand(model):
    """format.md §6 step 6 from the arrays alone: the lookup without the store plus the
    weighted corrections found by a search of each neighbour pair's key, clamped at 0."""
    from sparsebtf.runtime import angular_weights

    c = encode(smooth_btf(8), model, tau=(32, 8, 8), eps=0.0, progress=False)
    lit = replace(c, highlights=random_store(c, seed=3, share=0.6, scale=0.5))
    a = RuntimeBTF(lit).arrays()
    assert "highlight_keys" not in RuntimeBTF(c).arrays()
    assert a["highlight_offsets"].shape == (c.n_points + 1,)
    rng = np.random.default_rng(1)
    wi = rng.normal(size=(40, 3))
    wo = rng.normal(size=(40, 3))
    wi[:, 2], wo[:, 2] = np.abs(wi[:, 2]) + 0.1, np.abs(wo[:, 2]) + 0.1
    wi /= np.linalg.norm(wi, axis=1, keepdims=True)
    wo /= np.linalg.norm(wo, axis=1, keepdims=True)
    texel = rng.integers(0, 8, (40, 2))
    base = RuntimeBTF(c).evaluate(wi, wo, texel=texel).astype(np.float64)
    li, lw = angular_weights(a["lights_xyz"], wi, "linear")
    vi, vw = angular_weights(a["views_xyz"], wo, "linear")
    want = base.copy()
    for q, (row, col) in enumerate(texel):
        p = row // 4 + 2 * (col // 4)
        lo, hi = a["highlight_offsets"][p], a["highlight_offsets"][p + 1]
        keys = a["highlight_keys"][lo:hi]
        for x in range(li.shape[1]):
            for y in range(vi.shape[1]):
                key = (((row % 4) * 4 + col % 4) * 13 + li[q, x]) * 13 + vi[q, y]
                j = np.searchsorted(keys, key)
                if j < keys.size and keys[j] == key:
                    want[q] += lw[q, x] * vw[q, y] * a["highlight_rgb"][lo + j]
    got = RuntimeBTF(lit).evaluate(wi, wo, texel=texel)
    np.testing.assert_allclose(got, np.maximum(want, 0), rtol=1e-5, atol=1e-6)
    assert np.abs(got - base).max() > 0.05  # the store changed the values


def test_top_gains_keep_the_largest_positive_gains():
    from sparsebtf.codec.highlights import _TopGains

    rng = np.random.default_rng(0)
    top = _TopGains(cap=50)
    every = []
    for point in range(6):
        gain = rng.exponential(size=40)
        gain[::5] = 0.0  # exact nodes (reference = decode) never pay
        gain[1::7] = -1e-3  # nor do nodes binary16 would make worse
        rgb = rng.normal(size=(40, 3)).astype(np.float16)
        top.add(gain, point, rgb)
        every += [(g, point, k, rgb[k]) for k, g in enumerate(gain) if g > 0]
    g, pts, keys, rgb = top.sorted()
    want = sorted(every, key=lambda e: -e[0])[:50]
    np.testing.assert_allclose(g, [e[0] for e in want])
    assert set(zip(pts.tolist(), keys.tolist(), strict=True)) == {(e[1], e[2]) for e in want}
    for gi, p, k, v in zip(g, pts, keys, rgb, strict=True):
        assert any(e[1] == p and e[2] == k and np.array_equal(e[3], v) for e in want)
        assert gi > 0

"""The highlight store (issue 46): the encoder's choice of base code, entries (tinted or not)
and lobes within each level's bytes, the decoders and the byte accounting (the files:
``test_highlight_file.py``)."""

from __future__ import annotations

import itertools
from dataclasses import replace

import h5py
import numpy as np
import pytest

from sparsebtf.codec import encode, encode_levels
from sparsebtf.codec.highlights import base_taus, choose_highlights
from sparsebtf.data.btf import ArrayBTF
from sparsebtf.errors import BTFInputError
from sparsebtf.learning.highlights import Highlights, node_keys
from sparsebtf.learning.lobes import LOBE_BYTES, lobe_values
from sparsebtf.runtime import RuntimeBTF
from sparsebtf.runtime.dense import DecodedBTF
from sparsebtf.storage import storage_report
from sparsebtf.storage.accounting import paper_storage
from sparsebtf.storage.highlight_file import (
    TINT_SCHEMA,
)

from .conftest import smooth_btf, tiny_model
from .highlight_materials import LEVELS, glossy_btf, tinted_btf
from .test_highlight_decode import random_store


@pytest.fixture(scope="module")
def model():
    return tiny_model(max_iter=2)


@pytest.fixture(scope="module")
def glossy():
    return glossy_btf()


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

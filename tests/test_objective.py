"""Coding objectives (issue 32): ``encode --objective log|linear|display``.

* ``log`` is today's rule bit for bit: the default call, ``objective="log"`` and a reference
  built here from the kernel's own pieces (projection, top-k, the release's count rule) give
  the same codes;
* on a point with a few very bright values, the linear objective's error never grows with τ,
  its stored errors are the decoded BTF's (recomputed here), and it is never above the log
  rule's code at the same τ;
* the objective round-trips through the coded file, ``info`` shows it, old files read as
  ``log``; the resume fingerprint holds it;
* an unknown objective is one clear error (library and CLI).
"""

from __future__ import annotations

import numpy as np
import pytest

from sparsebtf.cli.main import main
from sparsebtf.codec.encode import encode, encode_levels
from sparsebtf.colour import YUV_TO_RGB
from sparsebtf.data.btf import ArrayBTF
from sparsebtf.errors import BTFInputError
from sparsebtf.learning.codes import rule_keys, topk_abs
from sparsebtf.learning.coding import sparse_code
from sparsebtf.learning.tensor import project
from sparsebtf.points.grid import PatchGrid, iter_points
from sparsebtf.points.preprocessing import Preprocessor

from .conftest import smooth_btf, tiny_model

LEVELS = [(16, 4, 4), (32, 8, 8), (64, 16, 16), (128, 32, 32)]


@pytest.fixture(scope="module")
def model():
    return tiny_model()


def highlight_btf() -> ArrayBTF:
    """``smooth_btf(8)`` with a highlight: one texel's 3x3 (light, view) block 80x brighter."""
    b = smooth_btf(8)
    a = b.to_array().copy()
    a[1, 2, 3:6, 4:7, :] *= 80
    return ArrayBTF(a, b.lights, b.views, name="highlight")


def _arrays(coded):
    return {ch: (c.membership, c.counts, c.values, c.locations, c.errors)
            for ch, c in coded.codes.items()}  # fmt: skip


def _same(a, b) -> None:
    for ch in a:
        for x, y in zip(a[ch], b[ch], strict=True):
            assert x.dtype == y.dtype and np.array_equal(x, y), ch


def _reference_codes(batch, dicts, tau, eps):
    """The paper's rule from the kernel's pieces, point by point and dictionary by dictionary:
    (membership, counts, values, flat indices) with values by decreasing magnitude."""
    size = int(np.prod(batch.shape[1:]))
    member, counts, values, flat = [], [], [], []
    for x in batch:
        energy = float(np.dot(x.ravel().astype(np.float64), x.ravel().astype(np.float64)))
        opts = []
        for k in range(dicts[0].shape[0]):
            s = project(x[None], [np.asarray(d[k], np.float32) for d in dicts]).reshape(-1)
            idx = topk_abs(s, tau)
            n, e = rule_keys((s[idx].astype(np.float64) ** 2)[None], energy, size, tau, eps)
            opts.append((int(n[0]), float(e[0]), k, idx[: int(n[0])], s[idx[: int(n[0])]]))
        n, _, k, idx, vals = min(opts, key=lambda o: (o[0], o[1], o[2]))
        member.append(k)
        counts.append(n)
        values.append(vals)
        flat.append(idx)
    return np.array(member), np.array(counts), np.concatenate(values), np.concatenate(flat)


def test_log_objective_is_todays_rule_bit_for_bit(model):
    btf = smooth_btf(8)
    default = encode_levels(btf, model, LEVELS[:2], eps=1e-3, progress=False)
    log = encode_levels(btf, model, LEVELS[:2], eps=1e-3, progress=False, objective="log")
    for d, g in zip(default, log, strict=True):
        _same(_arrays(d), _arrays(g))
        assert "objective" not in g.params and g.objective == "log"
    # the kernel against a reference from its pieces, on the encoder's own standardised points
    pre = Preprocessor(default[0].stats)
    n = PatchGrid.for_btf(btf, model.patch).n_points
    ((_, x),) = list(iter_points(btf, pre, model.patch, np.arange(n), n, channels_first=True))
    for c, ch in enumerate("YUV"):
        xc = np.ascontiguousarray(x[c])
        got = sparse_code(xc, model.dictionaries[ch], 16, 1e-3, np.float32, None)
        m, cnt, vals, flat = _reference_codes(xc, model.dictionaries[ch], 16, 1e-3)
        assert np.array_equal(got.membership, m) and np.array_equal(got.counts, cnt)
        assert np.array_equal(got.values, vals.astype(np.float32))
        assert np.array_equal(got.locations,
                              np.stack(np.unravel_index(flat, xc.shape[1:]), 1))  # fmt: skip


def _channel_linear_error(coded, ch, btf) -> np.ndarray:
    """(P,) the linear objective's error of channel ``ch`` recomputed from the decoded BTF:
    the decoded values with that channel's residual only, clamped like every decoder."""
    from sparsebtf.runtime.dense import DecodedBTF

    c = "YUV".index(ch)
    pre = Preprocessor(coded.stats)
    truth = btf.to_array().astype(np.float64)
    z_true = pre.forward(truth)
    z_dec = DecodedBTF(coded).read_standardised(slice(None), slice(None), slice(None),
                                                slice(None)).astype(np.float64)  # fmt: skip
    z = z_true.copy()
    z[..., c] = z_dec[..., c]
    err = (pre.inverse(z) - pre.inverse(z_true)) ** 2
    p = coded.patch
    h, w = btf.height // p, btf.width // p
    per = err.reshape(h, p, w, p, -1).mean(axis=(1, 3, 4))  # (row block, col block)
    return per.T.ravel()  # release order: point = row_block + n_row_blocks * col_block


def _point_mse(coded, btf) -> np.ndarray:
    """(P,) linear-RGB MSE of each data point of the decoded BTF."""
    from sparsebtf.runtime.dense import DecodedBTF

    err = (DecodedBTF(coded).to_array().astype(np.float64) - btf.to_array()) ** 2
    p = coded.patch
    per = err.reshape(btf.height // p, p, btf.width // p, p, -1).mean(axis=(1, 3, 4))
    return per.T.ravel()  # release order: point = row_block + n_row_blocks * col_block


def _as_stored(coded, path):
    """``coded`` as its file gives it back (values at the file's precision)."""
    from sparsebtf.storage import load_coded, save_coded

    save_coded(coded, path)
    return load_coded(path).attach(coded.model)


def test_linear_objective_never_worse_with_more_coefficients_on_a_highlight(model, tmp_path):
    btf = highlight_btf()
    lin = encode_levels(btf, model, LEVELS, eps=0.0, progress=False, objective="linear")
    log = encode_levels(btf, model, LEVELS, eps=0.0, progress=False)
    # both as their files give them back: the linear codes are judged at the file's
    # precision, the log ones rounded when written
    mse_lin = np.array([_point_mse(_as_stored(c, tmp_path / f"lin{j}.h5"), btf)
                        for j, c in enumerate(lin)])  # (levels, P)  # fmt: skip
    mse_log = np.array([_point_mse(_as_stored(c, tmp_path / f"log{j}.h5"), btf)
                        for j, c in enumerate(log)])  # fmt: skip
    # every point: no level worse than the one below (by construction)
    assert (np.diff(mse_lin, axis=0) <= 1e-5 * mse_lin[1:]).all()
    # and none worse than the log rule's code (the level's choice, and the level-of-detail
    # walk keeps a channel's set-aside coefficients where dropping them would raise the
    # point's error: dropping them whenever they raised the channel's own error was 5% worse
    # here at level 128)
    assert (mse_lin <= mse_log * (1 + 1e-5)).all()
    for ch in "YUV":
        for c_lin, t in zip(lin, LEVELS, strict=True):
            # each channel's stored error is its own error in the objective (the other two
            # exact), recomputed from the decoded BTF; counts within the level's cap
            got = _channel_linear_error(c_lin, ch, btf)
            np.testing.assert_allclose(c_lin.codes[ch].errors, got, rtol=2e-3, atol=1e-9)
            assert c_lin.codes[ch].counts.max() <= t["YUV".index(ch)]
    # and the objective makes a difference (measured: point 3 at level 16, 0.141 against the
    # log rule's 2.28)
    assert (mse_lin < 0.95 * mse_log).any()


def test_level_of_detail_order_never_raises_the_objective_error(model, tmp_path):
    """Every point of a linear-objective file: the objective's error of the first ⌈f·τ_c⌉
    coefficients of every channel (what the runtime's level of detail reads at fraction f)
    does not grow from one of f = 0.1, 0.2, …, 1 to the next, in the file's order, which
    survives a save and load and which the runtime's level of detail truncates."""
    import math

    from sparsebtf.codec.encode import batch_errors
    from sparsebtf.learning.lod_order import LOD_FRACTIONS
    from sparsebtf.learning.objective import joint_error
    from sparsebtf.learning.tensor import reconstruct_sparse
    from sparsebtf.runtime import RuntimeBTF
    from sparsebtf.runtime.lod import LATER_FRACTION, MIN_FRACTION, SAMPLED_FRACTION
    from sparsebtf.storage import load_coded, save_coded

    # the stops are the fractions the runtime reads
    assert {LATER_FRACTION, SAMPLED_FRACTION, MIN_FRACTION, 1.0} <= set(LOD_FRACTIONS)
    btf = highlight_btf()
    tau = (64, 16, 16)
    coded = encode(btf, model, tau=tau, eps=0.0, progress=False, objective="linear")
    save_coded(coded, tmp_path / "c.h5")
    back = load_coded(tmp_path / "c.h5")
    for ch in "YUV":  # the order is the file's (values already at the file's precision)
        a, b = coded.codes[ch], back.codes[ch]
        assert np.array_equal(a.counts, b.counts) and np.array_equal(a.values, b.values)
        assert np.array_equal(a.locations, b.locations)
    pre = Preprocessor(coded.stats)
    n = PatchGrid.for_btf(btf, model.patch).n_points
    ((_, x),) = list(iter_points(btf, pre, model.patch, np.arange(n), n, channels_first=True))
    errors = batch_errors(x, pre, "linear")

    def curve(coded_btf, i, counts):
        """The point's joint error with each channel's first counts[c] coefficients."""
        res = []
        for c, ch in enumerate("YUV"):
            codes = coded_btf.codes[ch]
            loc, val = codes.point(i)
            mats = [np.asarray(d[codes.membership[i]], np.float64)
                    for d in model.dictionaries[ch]]  # fmt: skip
            k = counts[c]
            res.append(reconstruct_sparse(loc[:k], val[:k].astype(np.float64), mats)
                       - np.asarray(x[c][i], np.float64))  # fmt: skip
        return joint_error(errors, i, res)

    def at_fractions(coded_btf, i):  # no coefficient, then each fraction
        return np.array([curve(coded_btf, i, [math.ceil(f * t - 1e-9) for t in tau])
                         for f in (0.0, *LOD_FRACTIONS)])  # fmt: skip

    for i in range(n):
        e = at_fractions(back, i)
        assert np.all(np.diff(e) <= 1e-5 * e[1:]), (i, e)
    # the runtime truncates that order: its first k are the file's first k
    rt = RuntimeBTF(back.attach(model), tau=(5, 3, 3))
    for ch, k in zip("YUV", (5, 3, 3), strict=True):
        got, full = rt.coded.codes[ch], back.codes[ch]
        for i in range(n):
            assert np.array_equal(got.point(i)[1], full.point(i)[1][:k])
    # a blend re-cuts the summed coefficients by magnitude: the log rule's order, so recorded
    from sparsebtf.runtime.blend import blend

    mixed = blend([coded, coded], alpha=0.5, progress=False)
    assert mixed.objective == "log" and "objective" not in mixed.params
    save_coded(mixed, tmp_path / "b.h5")
    assert load_coded(tmp_path / "b.h5").objective == "log"  # its magnitude order checked


def test_objective_round_trips_and_info_shows_it(model, tmp_path, capsys):
    from sparsebtf.storage import load_coded, save_coded, save_model

    coded = encode(highlight_btf(), model, tau=(32, 8, 8), eps=0.0, progress=False,
                   objective="display")  # fmt: skip
    assert coded.objective == "display" and coded.params["objective"] == "display"
    save_coded(coded, tmp_path / "c.h5")
    back = load_coded(tmp_path / "c.h5")
    assert back.objective == "display"
    for ch in "YUV":  # the file keeps values in binary16, in the same order
        a, b = coded.codes[ch], back.codes[ch]
        assert np.array_equal(a.membership, b.membership) and np.array_equal(a.counts, b.counts)
        assert np.array_equal(a.locations, b.locations)
        assert np.array_equal(a.values.astype(np.float16), b.values.astype(np.float16))
        np.testing.assert_allclose(a.errors, b.errors, rtol=1e-6)
    save_model(model, tmp_path / "m.h5")
    assert main(["info", str(tmp_path / "c.h5"), "-m", str(tmp_path / "m.h5")]) == 0
    assert "display: each point's code judged by its error after the display mapping" in \
        capsys.readouterr().out  # fmt: skip
    # the CLI's encode records it too
    assert main(["encode", "synth:stone:8:1:tiny13", "-m", str(tmp_path / "m.h5"), "-o",
                 str(tmp_path / "s.h5"), "--tau", "16,4,4", "--objective", "linear"]) == 0
    assert load_coded(tmp_path / "s.h5").objective == "linear"
    plain = encode(smooth_btf(8), model, tau=(16, 4, 4), progress=False)
    save_coded(plain, tmp_path / "p.h5")
    assert load_coded(tmp_path / "p.h5").objective == "log"


def test_resume_fingerprint_holds_the_objective(model):
    from sparsebtf.codec.checkpoint import range_key
    from sparsebtf.codec.encode import FixedTau
    from sparsebtf.codec.jobs import Header

    h = Header.of(smooth_btf(8))
    plans = [FixedTau.for_model(model, [(16, 4, 4)], objective=o) for o in ("log", "linear")]
    keys = [range_key(h, model, p, None, 4, [(0, 4)]) for p in plans]
    assert keys[0] != keys[1]
    assert keys[1]["plan_parameters"]["objective"] == "linear"


def test_unknown_objective_is_one_clear_error(model, tmp_path, capsys):
    with pytest.raises(BTFInputError, match="unknown coding objective 'lin'; choose one of "
                       "log, linear, display"):  # fmt: skip
        encode(smooth_btf(8), model, tau=(16, 4, 4), progress=False, objective="lin")
    from sparsebtf.storage import save_model

    save_model(model, tmp_path / "m.h5")
    with pytest.raises(SystemExit) as e:
        main(["encode", "synth:stone:8:1:tiny13", "-m", str(tmp_path / "m.h5"), "-o",
              str(tmp_path / "o.h5"), "--objective", "lin"])  # fmt: skip
    assert e.value.code == 2
    err = capsys.readouterr().err
    assert "--objective: invalid choice: 'lin'" in err and "Traceback" not in err
    assert not (tmp_path / "o.h5").exists()
    # a file that names an unknown objective is refused in one line
    from sparsebtf.errors import FileFormatError
    from sparsebtf.storage import load_coded, save_coded

    coded = encode(smooth_btf(8), model, tau=(16, 4, 4), progress=False)
    coded.params["objective"] = "lin"
    save_coded(coded, tmp_path / "bad.h5")
    with pytest.raises(FileFormatError, match="'objective' must be one of") as e:
        load_coded(tmp_path / "bad.h5")
    assert "\n" not in str(e.value)


def test_yuv_to_rgb_scale_of_the_linear_error():
    """E_c of a constant residual δ on a flat point is (I·expm1(M[r, c]·σ·δ))² averaged."""
    from sparsebtf.learning.objective import ChannelError

    log_rgb = np.full((1, 2, 2, 3, 3, 3), np.log(0.5 + 1e-3), dtype=np.float32)
    std = np.full((3, 3, 1), 0.7)
    err = ChannelError.for_batch("linear", log_rgb, std, None, 1e-3, 1)
    got = err(0, np.full((2, 2, 3, 3), 0.2))
    want = np.mean([(0.501 * np.expm1(YUV_TO_RGB[r, 1] * 0.7 * 0.2)) ** 2 for r in range(3)])
    assert got == pytest.approx(want, rel=1e-5)


def test_rate_control_codes_for_the_objective(model):
    from sparsebtf.codec.rate import encode_rate_levels

    btf = highlight_btf()
    (lin,) = encode_rate_levels(btf, model, [400], objective="linear", progress=False)
    (log,) = encode_rate_levels(btf, model, [400], progress=False)
    assert lin.objective == "linear" and log.objective == "log"
    assert lin.params["rate_control"]["weighting"] == "exact"
    # the marginal point ends on a count its walk evaluated: below the target by less than
    # one block of the walk (5 bytes per coefficient), never above
    from sparsebtf.learning.lod_order import walk_stops

    block = int(np.diff(walk_stops(4096)).max())
    assert 0 <= 400 - lin.params["rate_control"]["material_bytes"] < 5 * block
    (disp,) = encode_rate_levels(btf, model, [400], objective="display", progress=False)
    assert disp.params["rate_control"]["weighting"] == "exact"
    with pytest.raises(BTFInputError, match="weighting 'log' applies to the log objective"):
        encode_rate_levels(btf, model, [400], objective="linear", weighting="log",
                           progress=False)  # fmt: skip


def test_linear_objective_on_a_dask_cluster_equals_one_process(model):
    pytest.importorskip("distributed")
    btf = highlight_btf()
    want = encode_levels(btf, model, LEVELS[:2], eps=0.0, progress=False, objective="linear")
    got = encode_levels(btf, model, LEVELS[:2], eps=0.0, progress=False, objective="linear",
                        workers=1)  # fmt: skip
    for w, g in zip(want, got, strict=True):
        _same(_arrays(w), _arrays(g))
        assert g.objective == "linear"


def test_rate_control_more_bytes_never_raise_the_objective_error(model):
    """Rate control under the linear objective spends on exact error curves: at a larger
    target no point's error in the objective (each channel's, the other two exact) is
    larger, so neither is the material's; the stored errors are the decoded BTF's."""
    from sparsebtf.codec.rate import encode_rate_levels

    btf = highlight_btf()
    coded = encode_rate_levels(btf, model, [260, 400, 700], objective="linear",
                               progress=False)  # fmt: skip
    for ch in "YUV":
        errs = np.array([c.codes[ch].errors for c in coded])  # (targets, P)
        assert (np.diff(errs, axis=0) <= 1e-9).all(), ch
        nnz = [c.codes[ch].nnz for c in coded]
        assert nnz == sorted(nnz)
        for c in coded:
            np.testing.assert_allclose(c.codes[ch].errors, _channel_linear_error(c, ch, btf),
                                       rtol=2e-3, atol=1e-9)  # fmt: skip
    total = [sum(float(c.codes[ch].errors.sum()) for ch in "YUV") for c in coded]
    assert total[0] > total[1] > total[2]


def test_hull_gains_fall_along_a_point():
    from sparsebtf.learning.rate_control import hull_gains

    # a curve with a bend the hull skips (1 → 3 falls by 6 in two steps, 0 → 1 by 1)
    g = hull_gains(np.array([[10.0, 9.0, 8.5, 2.5, 2.0, np.nan]]))
    # hull: 0, 3, 4 → slopes 7.5/3 = 2.5 on positions 1–3, then 0.5; -inf past the curve
    np.testing.assert_allclose(g[0, 1:5], [2.5, 2.5, 2.5, 0.5])
    assert g[0, 5] == -np.inf and (np.diff(g[0, 1:5]) <= 0).all()
    # a walk's curve known only at its stops (NaN between): the hull of the known counts,
    # and the allocation's counts rounded down to a known one
    from sparsebtf.learning.rate_control import known_count

    gapped = np.array([[10.0, 9.0, np.nan, 2.5, np.nan, 2.0, np.nan]])
    g = hull_gains(gapped)
    np.testing.assert_allclose(g[0, 1:6], [2.5, 2.5, 2.5, 0.25, 0.25])
    assert g[0, 6] == -np.inf
    assert known_count(gapped, np.array([4])).tolist() == [3]
    assert known_count(gapped, np.array([6])).tolist() == [5]
    assert known_count(np.array([[1.0, np.nan]]), np.array([1])).tolist() == [0]


def test_joint_walk_sets_aside_a_harmful_coefficient(model):
    """Codes whose magnitude order raises the point's error at the runtime's fractions (each
    point's largest Y coefficient negated and doubled, so it is still read first): the
    level-of-detail order falls at every fraction, errs no more than the codes as given, and
    the levels' errors do not rise."""
    import math

    from sparsebtf.codec.encode import batch_errors
    from sparsebtf.learning.coding import SparseCodes
    from sparsebtf.learning.lod_order import LOD_FRACTIONS, lod_orders
    from sparsebtf.learning.objective import joint_error
    from sparsebtf.learning.tensor import reconstruct_sparse

    btf = highlight_btf()
    taus = [(32, 8, 8), (64, 16, 16)]
    given = encode_levels(btf, model, taus, eps=0.0, progress=False)
    pre = Preprocessor(given[0].stats)
    n = PatchGrid.for_btf(btf, model.patch).n_points
    ((_, x),) = list(iter_points(btf, pre, model.patch, np.arange(n), n, channels_first=True))
    errors = batch_errors(x, pre, "linear")
    xs = [np.ascontiguousarray(x[c]) for c in range(3)]
    dicts = [model.dictionaries[ch] for ch in "YUV"]
    codes = []
    for ch in "YUV":
        per_level = []
        for g in given:
            c = g.codes[ch]
            vals = c.values.copy()
            if ch == "Y":
                starts = np.concatenate([[0], np.cumsum(c.counts)[:-1]])
                vals[starts] *= -2.0  # still the largest, now harmful
            per_level.append(SparseCodes(c.mode_sizes, c.membership, c.counts, vals,
                                         c.locations, c.errors))  # fmt: skip
        codes.append(per_level)
    caps = [list(t) for t in zip(*taus, strict=True)]
    walked, unjudged = lod_orders(xs, errors, codes, dicts, caps)

    def joint(cs, j, i, frac):
        res = []
        for c in range(3):
            loc, val = cs[c][j].point(i)
            k = math.ceil(frac * taus[j][c] - 1e-9)
            mats = [np.asarray(d[cs[c][j].membership[i]], np.float64) for d in dicts[c]]
            res.append(reconstruct_sparse(loc[:k], val[:k].astype(np.float64), mats)
                       - np.asarray(xs[c][i], np.float64))  # fmt: skip
        return joint_error(errors, i, res)

    fracs = (0.0, *LOD_FRACTIONS)
    rose = 0
    for j in range(len(taus)):
        for i in range(n):
            before = np.array([joint(codes, j, i, f) for f in fracs])
            after = np.array([joint(walked, j, i, f) for f in fracs])
            rose += int(np.any(np.diff(before) > 0))
            assert np.all(np.diff(after) <= 1e-5 * after[1:]), (j, i, after)
            assert after[-1] <= before[-1] * (1 + 1e-4)
            if j:
                assert after[-1] <= joint(walked, 0, i, 1.0) * (1 + 1e-5)
    assert rose == 2 * n  # the magnitude order rose on every point and level
    assert unjudged == 0

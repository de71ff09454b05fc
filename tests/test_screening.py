"""Screening of the dictionaries before the exact projections (issue 22 item 1): all K
candidates are the exhaustive rule bit for bit; fewer follow the paper's rule among the
candidates; the coded file, ``info``, the CLI and the checkpoints know which rule ran."""

from __future__ import annotations

import json
import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from sparsebtf.cli.main import main
from sparsebtf.codec import checkpoint as ckmod
from sparsebtf.codec import encode, encode_to_size
from sparsebtf.errors import BTFInputError, FileFormatError
from sparsebtf.learning import coding
from sparsebtf.learning.coding import screen_dictionaries, sparse_code_levels
from sparsebtf.learning.ensemble import random_orthonormal
from sparsebtf.learning.tensor import reconstruct
from sparsebtf.storage import load_coded, save_coded

from .conftest import smooth_btf, tiny_model

SHAPE = (4, 4, 20, 20)
K = 4
LEVELS = [12, 40, 300]
FIELDS = ("membership", "counts", "values", "locations", "errors")


@pytest.fixture(autouse=True)
def _partial(monkeypatch):
    """r = 8: 16 of the 20 light and 4 of the 20 view columns, so the screening's projection is
    partial on these shapes."""
    monkeypatch.setattr(coding, "SCREEN_COLUMNS", 8)
    monkeypatch.setattr(coding, "SCREEN_DEPTH", 1)


def test_screening_width_grows_with_tau(monkeypatch):
    monkeypatch.undo()
    assert coding.SCREEN_COLUMNS == 24 and coding.SCREEN_ASPECT == 2
    # (light, view) columns: r·2 and r/2 of the square rule's r (24, 24, 36, 54)
    assert [coding.screen_columns(t, 100) for t in (64, 885, 2003, 4483)] == [
        (48, 12), (48, 12), (72, 18), (108, 27)]
    assert coding.screen_columns(885, 100, aspect=1) == (24, 24)  # the square window
    # fewer light columns than asked: the view mode takes more, the count r² stays
    r3, r4 = coding.screen_columns(4483, 100, n_light=90)
    assert r3 == 90 and r4 == 33 and r3 * r4 >= 54 * 54
    assert coding.partial_flops((10, 10, 151, 151), (48, 12)) < 0.65 * coding.partial_flops(
        (10, 10, 151, 151), (24, 24))


def _ensemble(seed: int = 0) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    return [np.stack([random_orthonormal(m, rng) for _ in range(K)]) for m in SHAPE]


def _points(dicts: list[np.ndarray], n: int = 6, seed: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Points sparse on a chosen dictionary each (plus noise): (points, planted k)."""
    rng = np.random.default_rng(seed)
    planted = rng.integers(0, K, n)
    out = []
    for k in planted:
        s = np.zeros(SHAPE)
        idx = rng.choice(s.size, 30, replace=False)
        s.flat[idx] = rng.normal(size=30) * np.geomspace(5, 0.1, 30)
        x = reconstruct(s[None], [d[k] for d in dicts])[0]
        out.append(x + 0.01 * rng.normal(size=SHAPE))
    return np.asarray(out, dtype=np.float32), planted


def _same(a: coding.SparseCodes, b: coding.SparseCodes) -> bool:
    return all(np.array_equal(getattr(a, f), getattr(b, f)) for f in FIELDS)


@pytest.mark.parametrize("eps", [0.0, 1e-4])
def test_all_candidates_equal_exhaustive_bit_for_bit(eps, monkeypatch):
    dicts = _ensemble()
    x, _ = _points(dicts)
    ref = sparse_code_levels(x, dicts, LEVELS, eps)
    for c in (K, K + 3):
        got = sparse_code_levels(x, dicts, LEVELS, eps, candidates=c)
        assert all(_same(a, b) for a, b in zip(ref, got, strict=True))
    # the screened code path itself (mask, sentinels, rule among the candidates) with all K
    monkeypatch.setattr(coding, "coding_rule", lambda c, k: ("screened", k))
    got = sparse_code_levels(x, dicts, LEVELS, eps, candidates=K)
    assert all(_same(a, b) for a, b in zip(ref, got, strict=True))


@pytest.mark.parametrize("c", [1, 2])
def test_screened_follows_the_rule_among_its_candidates(c):
    dicts = _ensemble()
    x, planted = _points(dicts, n=8)
    eps = 1e-4
    wide = screen_dictionaries(x, dicts, LEVELS, eps, c, margin=math.inf)
    assert (wide.sum(axis=1) >= c).all() and (wide.sum(axis=1) <= c * len(LEVELS)).all()
    mask = screen_dictionaries(x, dicts, LEVELS, eps, c)
    assert (mask <= wide).all() and (mask.sum(axis=1) >= 1).all()
    assert mask[np.arange(len(x)), planted].all()  # the planted dictionary always survives
    got = sparse_code_levels(x, dicts, LEVELS, eps, candidates=c)
    single = [sparse_code_levels(x, [d[k : k + 1] for d in dicts], LEVELS, eps) for k in range(K)]
    for j in range(len(LEVELS)):
        for i in range(len(x)):
            ks = np.flatnonzero(mask[i])
            keys = [(single[k][j].counts[i], single[k][j].errors[i]) for k in ks]
            best = int(ks[min(range(len(ks)), key=keys.__getitem__)])  # sparsest, least error
            assert got[j].membership[i] == best
            assert got[j].counts[i] == single[best][j].counts[i]
            assert got[j].errors[i] == single[best][j].errors[i]
            for a, b in zip(got[j].point(i), single[best][j].point(i), strict=True):
                assert np.array_equal(a, b)


@pytest.mark.parametrize("c", [None, 2])
def test_batches_coded_side_by_side_equal_one_call_each(c, monkeypatch):
    """Several batches (a batch's Y, U, V) on their own ensembles and levels, every point
    one task, one wait on the worker threads: the codes of one call per batch."""
    dicts, other = _ensemble(), _ensemble(seed=5)
    x, _ = _points(dicts)
    y, _ = _points(other, n=3, seed=7)
    ref = [sparse_code_levels(x, dicts, LEVELS, 1e-4, candidates=c),
           sparse_code_levels(y, other, [30], 1e-4, candidates=c)]  # fmt: skip
    waits = []
    inner = coding.parallel_map
    monkeypatch.setattr(coding, "parallel_map", lambda f, items: waits.append(1) or inner(f, items))
    got = coding.sparse_code_batches([x, y], [dicts, other], [LEVELS, [30]], 1e-4,
                                     candidates=c)  # fmt: skip
    assert len(waits) == 1
    for a, b in zip(got, ref, strict=True):
        assert len(a) == len(b) and all(_same(p, q) for p, q in zip(a, b, strict=True))
    # levels in any order, repeated: the dictionaries projected are screen_dictionaries' own,
    # the window too (wider for τ = 300 than for τ = 12 here)
    monkeypatch.setattr(coding, "SCREEN_DEPTH", 4)
    assert coding.screen_columns(300, 16, 20) != coding.screen_columns(12, 16, 20)
    made = []
    inner_p = coding.project_into
    monkeypatch.setattr(coding, "project_into",
                        lambda b, m, bufs: made.append(id(m)) or inner_p(b, m, bufs))  # fmt: skip
    # points of no dictionary: close rankings, so the levels the screening sees matter
    x2 = np.random.default_rng(11).standard_normal((12, *SHAPE)).astype(np.float32)
    x2 += _points(dicts, n=12, seed=11)[0]
    mixed = coding.sparse_code_batches([x2], [dicts], [[300, 12, 40, 12]], 0.0, candidates=c)
    mask = (np.ones((12, K), bool) if c is None
            else screen_dictionaries(x2, dicts, [300, 12, 40, 12], 0.0, c))  # fmt: skip
    assert len(made) == mask.sum()
    ref2 = sparse_code_levels(x2, dicts, [12, 40, 300], 0.0, candidates=c)
    assert all(_same(p, q) for p, q in zip(mixed[0], [ref2[2], ref2[0], ref2[1], ref2[0]],
                                           strict=True))  # fmt: skip
    with pytest.raises(BTFInputError, match="one of each per batch"):
        coding.sparse_code_batches([x, y], [dicts], [LEVELS, [30]])


def test_margin_keeps_a_close_second_only():
    """A second candidate far behind the first (a point planted on one dictionary) is dropped;
    one within the margin (a copy of the planted dictionary: the same partial error) stays."""
    dicts = _ensemble()
    x, planted = _points(dicts, n=8)
    mask = screen_dictionaries(x, dicts, [40], 0.0, 2)
    assert (mask.sum(axis=1) == 1).all() and mask[np.arange(len(x)), planted].all()
    assert (screen_dictionaries(x, dicts, [40], 0.0, 2, margin=math.inf).sum(axis=1) == 2).all()
    twins = [np.concatenate([d, d[planted[0]][None]]) for d in dicts]
    mask = screen_dictionaries(x[:1], twins, [40], 0.0, 2)
    assert mask[0, planted[0]] and mask[0, K] and mask.sum() == 2


def test_candidates_below_one_refused():
    dicts = _ensemble()
    x, _ = _points(dicts, n=1)
    with pytest.raises(BTFInputError, match="candidates must be >= 1"):
        sparse_code_levels(x, dicts, [12], 0.0, candidates=0)


@pytest.fixture(scope="module")
def model():
    return tiny_model()


@pytest.fixture(scope="module")
def model_file(model, tmp_path_factory) -> Path:
    from sparsebtf.storage import save_model

    path = tmp_path_factory.mktemp("model") / "tiny.h5"
    save_model(model, path)
    return path


def test_file_records_the_rule(model, tmp_path):
    btf = smooth_btf(5)
    screened = encode(btf, model, tau=(16, 4, 4), candidates=1, progress=False)
    exhaustive = encode(btf, model, tau=(16, 4, 4), candidates=None, progress=False)
    all_k = encode(btf, model, tau=(16, 4, 4), candidates=3, progress=False)  # K = 3
    assert screened.params["dictionary_rule"] == "screened"
    got = load_coded(save_coded(screened, tmp_path / "s.h5"), model)
    assert got.dictionary_rule == ("screened", 1)
    for coded in (exhaustive, all_k):
        back = load_coded(save_coded(coded, tmp_path / "e.h5"), model)
        assert back.dictionary_rule == ("exhaustive", None)
        assert "dictionary_candidates" not in back.params
    for ch in model.channels:
        assert _same(all_k.codes[ch], exhaustive.codes[ch])
    # a file written before the record reads as exhaustive
    old = replace(screened, params={k: v for k, v in screened.params.items()
                                    if not k.startswith("dictionary_")})  # fmt: skip
    assert load_coded(save_coded(old, tmp_path / "o.h5"), model).dictionary_rule[0] == "exhaustive"


@pytest.mark.parametrize(
    "params, says",
    [
        ({"dictionary_rule": "fast"}, "'dictionary_rule' must be one of"),
        ({"dictionary_rule": "screened", "dictionary_candidates": 3}, "< K = 3"),
        ({"dictionary_rule": "screened", "dictionary_candidates": 0}, "integer >= 1"),
        ({"dictionary_rule": "screened"}, "found None"),
        ({"dictionary_rule": "exhaustive", "dictionary_candidates": 2}, "expected none"),
    ],
)
def test_insane_rule_refused_on_write_and_read(model, tmp_path, params, says):
    import h5py

    coded = encode(smooth_btf(5), model, tau=(16, 4, 4), candidates=1, progress=False)
    base = {k: v for k, v in coded.params.items() if not k.startswith("dictionary_")}
    bad = replace(coded, params={**base, **params})
    with pytest.raises(BTFInputError, match=says):
        save_coded(bad, tmp_path / "bad.h5")
    path = save_coded(coded, tmp_path / "ok.h5")
    with h5py.File(path, "r+") as f:  # the same values in a file written by someone else
        f.attrs["params_json"] = json.dumps({**base, **params})
    with pytest.raises(FileFormatError, match=says):
        load_coded(path, model)


def test_rate_control_screening(model):
    btf = smooth_btf(6)
    kw = {"target_bytes": 900, "per_material": True, "progress": False}
    exhaustive = encode_to_size(btf, model, candidates=None, **kw)
    all_k = encode_to_size(btf, model, candidates=3, **kw)
    screened = encode_to_size(btf, model, candidates=1, **kw)
    assert exhaustive.dictionary_rule == all_k.dictionary_rule == ("exhaustive", None)
    assert screened.dictionary_rule == ("screened", 1)
    for ch in model.channels:
        assert _same(all_k.codes[ch], exhaustive.codes[ch])


A = "synth:stone:16:1:tiny13"


def _cli(model_file: Path, out: Path, *extra: str) -> int:
    return main(["encode", A, "-m", str(model_file), "-o", str(out), "--tau", "16,4,4",
                 "--batch", "2", *extra])  # fmt: skip


def test_cli_exhaustive_and_candidates(model_file, tmp_path, capsys):
    assert _cli(model_file, tmp_path / "e.h5", "--exhaustive") == 0
    assert _cli(model_file, tmp_path / "s.h5", "--candidates", "1") == 0
    assert _cli(model_file, tmp_path / "d.h5") == 0  # the default: screened
    capsys.readouterr()
    rules = {}
    for name in ("e", "s", "d"):
        assert main(["info", str(tmp_path / f"{name}.h5"), "-m", str(model_file), "--json"]) == 0
        info = json.loads(capsys.readouterr().out)
        rules[name] = (info["params"].get("dictionary_rule"), info["dictionary_rule"])
    assert rules["e"][0] == "exhaustive" and rules["e"][1].startswith("exhaustive")
    assert rules["s"][0] == "screened" and rules["s"][1].startswith("screened: the 1 best")
    assert rules["d"][1].startswith(f"screened: the {coding.DEFAULT_CANDIDATES} best")
    assert _cli(model_file, tmp_path / "x.h5", "--candidates", "0") == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--candidates must be an integer >= 1" in err[0]
    assert not (tmp_path / "x.h5").exists()


def test_checkpoint_of_another_rule_refused(model_file, tmp_path, monkeypatch, capsys):
    out = tmp_path / "out.h5"
    save = ckmod.EncodeCheckpoint.save

    def stop(self, *args):
        save(self, *args)
        raise KeyboardInterrupt

    with monkeypatch.context() as m:
        m.setattr(ckmod.EncodeCheckpoint, "save", stop)
        assert _cli(model_file, out, "--candidates", "1") == 130
    capsys.readouterr()
    assert _cli(model_file, out, "--exhaustive", "--resume") == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "dictionary_rule" in err[0], err
    assert '"screened, 1 candidates" in the checkpoint, "exhaustive" now' in err[0]
    assert not out.exists()


@pytest.mark.parametrize("flag, want", [([], coding.DEFAULT_CANDIDATES), (["--exhaustive"], None)])
def test_bench_quality_runs_either_rule(tmp_path, monkeypatch, flag, want):
    from sparsebtf.evaluation import report, runner

    seen = {}

    def fake_run(out, cfg, **kw):
        seen["cfg"] = cfg
        return {"summary": {}}

    monkeypatch.setattr(runner, "run_quality", fake_run)
    assert main(["bench", "quality", "--quick", "--out", str(tmp_path / "b"), *flag]) == 0
    assert seen["cfg"].candidates == want
    line = report.rule_line({"candidates": want})
    assert ("exhaustive (every point" if want is None else "screened (the 2 best") in line
    assert "exhaustive (every point" in report.rule_line({})  # runs before the screening


@settings(max_examples=60, deadline=None)
@given(k=st.integers(1, 4), n=st.integers(1, 400), top=st.integers(1, 400),
       levels=st.integers(1, 50), seed=st.integers(0, 2**16))
def test_top_squares_is_the_sorted_partition(k, n, top, levels, seed):
    """The blocked pre-filter keeps every one of the ``top`` largest, ties included (few
    distinct values: ``levels``), and falls back where there are fewer blocks than ``top``."""
    top = min(top, n)
    sq = np.random.default_rng(seed).integers(0, levels, (k, n)).astype(np.float64) ** 2
    want = -np.sort(-np.partition(sq, n - top, axis=1)[:, n - top :])
    assert np.array_equal(coding._top_squares(sq, top), want)

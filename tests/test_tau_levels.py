"""Beyond the paper (issue 34): ensembles trained at several τ_l, learned τ_l, pre-clustering."""

import numpy as np
import pytest

from sparsebtf.codec import train
from sparsebtf.codec.levels import parse_tau_train
from sparsebtf.errors import BTFInputError, FileFormatError
from sparsebtf.learning.coding import sparse_code
from sparsebtf.learning.ensemble import DictionaryEnsemble
from sparsebtf.learning.init import dct_basis, kmedoids, precluster
from sparsebtf.learning.partitions import ArraySource
from sparsebtf.learning.tau_levels import forward_selection
from sparsebtf.learning.tensor import project
from sparsebtf.storage import load_model, save_model

from .conftest import smooth_btf, tiny_model
from .test_learning import _mixture

FIT = dict(tol=0, dtype="float64", progress=False)


@pytest.fixture(scope="module")
def levels_model():
    """K = 4 per channel: two dictionaries at 8/2/2, two at 32/6/6 (4x4 patches, tiny13)."""
    btfs = [smooth_btf(s) for s in range(3)]
    return train(btfs, n_dictionaries=4, tau_train="8,2,2/32,6,6", patch=4, sample=1.0,
                 max_iter=2, progress=False)  # fmt: skip


def _same(a, b):
    return all(np.array_equal(u, v) for u, v in zip(a, b, strict=True))


def test_parse_tau_train_spellings():
    assert parse_tau_train("256,32,32", "YUV") == ({"Y": [256], "U": [32], "V": [32]}, False)
    two = {"Y": [64, 256], "U": [8, 32], "V": [8, 32]}
    assert parse_tau_train("64,8,8/256,32,32", "YUV") == (two, False)
    assert parse_tau_train([(64, 8, 8), (256, 32, 32)], "YUV") == (two, False)
    assert parse_tau_train("learn:64,8,8/256,32,32", "YUV") == (two, True)
    assert parse_tau_train("learn", "YUV")[0]["Y"] == [64, 256, 885]
    with pytest.raises(BTFInputError, match="at least two levels"):
        parse_tau_train("learn:64,8,8", "YUV")


def test_several_levels_round_trip_with_each_dictionary_tau(levels_model, tmp_path):
    m = levels_model
    assert m.dictionary_taus("Y") == [8, 8, 32, 32]
    assert m.dictionary_taus("U") == [2, 2, 6, 6]
    assert m.tau_train == {"Y": 8, "U": 2, "V": 2}  # the smallest level
    assert m.training["Y"]["levels"][1]["tau"] == 32
    back = load_model(save_model(m, tmp_path / "levels.h5"))
    assert back.content_hash == m.content_hash
    assert {ch: back.dictionary_taus(ch) for ch in back.channels} == {
        ch: m.dictionary_taus(ch) for ch in m.channels}
    assert back.params["tau_train_levels"] == [{"Y": 8, "U": 2, "V": 2}, {"Y": 32, "U": 6, "V": 6}]
    # a damaged field is one line naming it
    m.params["tau_dictionaries"]["Y"] = [8, 8, 32]
    save_model(m, tmp_path / "bad.h5")
    with pytest.raises(FileFormatError, match="tau_dictionaries") as e:
        load_model(tmp_path / "bad.h5")
    assert "\n" not in str(e.value)
    m.params["tau_dictionaries"]["Y"] = [8, 8, 32, 32]


def test_old_single_level_file_reads_as_one_level(tmp_path):
    m = tiny_model()
    back = load_model(save_model(m, tmp_path / "one.h5"))
    assert "tau_dictionaries" not in back.params
    assert back.dictionary_taus("Y") == [16, 16, 16] and back.dictionary_taus("V") == [4, 4, 4]


def test_coder_picks_across_levels(levels_model):
    """The unchanged §3.3 rule codes over all K: coded at each level's τ, the points of the
    training materials go to dictionaries of that level (each to its least-error one)."""
    from sparsebtf.codec import encode_levels

    taus = levels_model.dictionary_taus("Y")
    chosen = {8: set(), 32: set()}
    for s in range(3):
        coded = encode_levels(smooth_btf(s), levels_model, [(8, 2, 2), (32, 6, 6)], eps=0.0,
                              progress=False)  # fmt: skip
        for t, c in zip((8, 32), coded, strict=True):
            chosen[t] |= {taus[k] for k in c.codes["Y"].membership.tolist()}
    assert 8 in chosen[8] and 32 in chosen[32]


def test_coder_rule_on_levels_is_least_error():
    x = _mixture(3, n=12)
    ens = DictionaryEnsemble(n_dictionaries=4, tau=[4, 16], max_iter=2, **FIT).fit(x)
    assert ens.taus_ == [4, 4, 16, 16] and ens.membership_.shape == (12, 2)
    codes = sparse_code(x, ens.dictionaries_, 16, dtype=np.float64)
    errs = []
    for k in range(4):
        s = project(x, [d[k] for d in ens.dictionaries_]).reshape(12, -1) ** 2
        errs.append((s.sum(1) - np.sort(s, axis=1)[:, -16:].sum(1)) / s.shape[1])
    assert np.array_equal(codes.membership, np.argmin(np.array(errs), axis=0))


def test_k_not_a_multiple_of_the_levels_is_one_line():
    with pytest.raises(BTFInputError, match="multiple of 3") as e:
        train([smooth_btf(0)], n_dictionaries=4, tau_train="8,2,2/16,4,4/32,6,6", patch=4,
              progress=False)  # fmt: skip
    assert "\n" not in str(e.value) and "(e.g. 6)" in str(e.value)


def test_several_levels_resume_after_an_interruption(tmp_path):
    x = _mixture(4, n=16)
    kw = dict(n_dictionaries=4, tau=[4, 16], max_iter=3, candidates=1, full_pass_every=2, **FIT)
    whole = DictionaryEnsemble(**kw).fit(x)

    class Interrupted(DictionaryEnsemble):
        def _save_checkpoint(self, state):
            super()._save_checkpoint(state)
            if self.tau == 16 and state.iteration == 2:  # in the second level
                raise KeyboardInterrupt

    ck = tmp_path / "ck.npz"
    with pytest.raises(KeyboardInterrupt):
        Interrupted(checkpoint=ck, **kw).fit(x)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ck_level1.npz", "ck_level2.npz"]
    resumed = DictionaryEnsemble(checkpoint=ck, **kw).fit(x)
    assert _same(resumed.dictionaries_, whole.dictionaries_)
    assert resumed.objective_ == whole.objective_
    with pytest.raises(BTFInputError, match="other training parameters"):
        DictionaryEnsemble(checkpoint=ck, **{**kw, "tau": [4, 12]}).fit(x)
    with pytest.raises(BTFInputError, match="several training sparsity levels"):
        DictionaryEnsemble(checkpoint=ck, **{**kw, "tau": 4}).fit(x)


def test_learned_levels_are_seeded_and_chosen_on_validation(tmp_path):
    x = _mixture(5, n=40)
    kw = dict(n_dictionaries=3, tau=[4, 16], learn_tau=True, max_iter=2, partition_size=8,
              **FIT)  # fmt: skip
    a = DictionaryEnsemble(**kw).fit(x)
    b = DictionaryEnsemble(checkpoint=tmp_path / "ck.npz", **kw).fit(x)
    assert _same(a.dictionaries_, b.dictionaries_) and a.taus_ == b.taus_
    assert set(a.taus_) <= {4, 16} and len(a.taus_) == 3
    assert a.validation_["points"] == 8  # one of the five partitions of 8 held out
    assert a.membership_.shape == (32, 2)  # the levels saw the other 32
    assert np.all(np.diff(a.validation_["scores"]) <= 0)  # each added dictionary helps
    with pytest.raises(BTFInputError, match="partitions"):
        DictionaryEnsemble(**{**kw, "partition_size": 64}).fit(x)
    # the validation coding levels: the same level fits (the checkpoints serve), another choice
    c = DictionaryEnsemble(checkpoint=tmp_path / "ck.npz", validation_taus=[100], **kw).fit(x)
    assert c.validation_["coding_taus"] == [100] and a.validation_["coding_taus"] == [4, 16]
    assert set(c.taus_) <= {4, 16}


def test_forward_selection_takes_the_best_complement():
    # 2 points, 3 pool dictionaries, 1 level: 0 fits point 0, 1 fits point 1, 2 is mediocre
    err = np.array([[[1.0], [9.0], [3.0]], [[9.0], [1.0], [3.0]]])
    assert forward_selection(err, 1)[0] == [2]
    assert forward_selection(err, 3)[0] == [2, 0, 1]
    assert forward_selection(err, 2)[0] == [2, 0]


def test_dct_basis_is_orthonormal_and_kmedoids_recovers_groups():
    for m in (1, 4, 13):
        d = dct_basis(m)
        assert np.allclose(d.T @ d, np.eye(m))
    rng = np.random.default_rng(0)
    pts = np.concatenate([rng.normal(0, 0.1, (5, 2)), rng.normal(5, 0.1, (5, 2))])
    dist = np.linalg.norm(pts[:, None] - pts[None], axis=2)
    g = kmedoids(dist, 2, np.random.default_rng(1))
    assert len(set(g[:5])) == 1 and len(set(g[5:])) == 1 and g[0] != g[5]


def test_precluster_groups_points_by_support():
    """Points sparse on two disjoint sets of DCT atoms fall in two groups."""
    shape = (4, 4, 5, 5)
    mats = [dct_basis(m) for m in shape]
    rng = np.random.default_rng(2)
    coeffs = np.zeros((12, *shape))
    flat = coeffs.reshape(12, -1)
    flat[:6, :6] = rng.uniform(1, 2, (6, 6))
    flat[6:, 100:106] = rng.uniform(1, 2, (6, 6))
    x = project(coeffs, [m.T for m in mats])  # synthesis: X = S ×_n D_n
    g = precluster(ArraySource(x), 2, 6, random_state=0)
    assert len(set(g[:6])) == 1 and len(set(g[6:])) == 1 and g[0] != g[6]


def test_preclustered_init_is_seeded_and_resumes_after_an_interruption(tmp_path):
    x = _mixture(6, n=16)
    kw = dict(n_dictionaries=3, tau=8, init="preclustered", max_iter=4, candidates=1,
              full_pass_every=2, random_state=3, **FIT)  # fmt: skip
    whole = DictionaryEnsemble(**kw).fit(x)
    assert _same(whole.dictionaries_, DictionaryEnsemble(**kw).fit(x).dictionaries_)
    other = DictionaryEnsemble(**{**kw, "init": "points"}).fit(x)
    assert not _same(whole.dictionaries_, other.dictionaries_)
    assert np.all(np.diff(whole.objective_) <= 1e-12 * whole.objective_[0])

    class Interrupted(DictionaryEnsemble):
        def _save_checkpoint(self, state):
            super()._save_checkpoint(state)
            if state.iteration == 1:
                raise KeyboardInterrupt

    ck = tmp_path / "ck.npz"
    with pytest.raises(KeyboardInterrupt):
        Interrupted(checkpoint=ck, **kw).fit(x)
    resumed = DictionaryEnsemble(checkpoint=ck, **kw).fit(x)
    assert _same(resumed.dictionaries_, whole.dictionaries_)
    assert resumed.objective_ == whole.objective_
    with pytest.raises(BTFInputError, match="other training parameters"):
        DictionaryEnsemble(checkpoint=ck, **{**kw, "init": "points"}).fit(x)


def test_cli_levels_learn_and_init(tmp_path, capsys):
    from sparsebtf.cli.main import main
    from sparsebtf.data.dense_file import write_dense

    paths = []
    for s in range(3):  # 27 points of 4x4: 4 partitions, one held out to learn tau
        write_dense(tmp_path / f"m{s}.h5", smooth_btf(s, size=12))
        paths.append(str(tmp_path / f"m{s}.h5"))
    base = ["train", *paths, "--patch", "4", "--sample", "1", "--iters", "1"]
    assert main([*base, "-o", str(tmp_path / "bad.h5"), "--dicts", "4",
                 "--tau-train", "8,2,2/16,4,4/32,6,6"]) != 0  # fmt: skip
    err = capsys.readouterr().err.strip()
    assert "multiple of 3" in err and len(err.splitlines()) == 1
    out = tmp_path / "learn.h5"
    assert main([*base, "-o", str(out), "--dicts", "2", "--tau-train", "learn:8,2,2/16,4,4",
                 "--tau-validation", "20,5,5", "--init", "preclustered"]) == 0  # fmt: skip
    m = load_model(out)
    assert m.params["init"] == "preclustered" and m.params["tau_learn"] is True
    assert m.params["tau_validation"] == {"Y": [20], "U": [5], "V": [5]}
    assert set(m.dictionary_taus("Y")) <= {8, 16} and len(m.dictionary_taus("Y")) == 2

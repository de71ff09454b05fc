"""The fast trainer: Z from the codes, by-products of the coding pass, candidate dictionaries."""

import numpy as np
import pytest

from sparsebtf.errors import BTFInputError
from sparsebtf.learning.coding import sparse_code
from sparsebtf.learning.ensemble import DictionaryEnsemble, random_orthonormal
from sparsebtf.learning.steps import (
    BatchCoding,
    code_step,
    cross_products,
    mode_fibres,
    pair_cross_products,
    pair_modes,
    sparse_cross_products,
)
from sparsebtf.learning.tensor import project, unfold

from .test_learning import _mixture

SHAPES = [(2, 3, 4, 3), (3, 3, 6, 6), (4, 4, 13, 13), (3, 3, 6, 6, 3), (5, 5, 5, 5), (4, 7)]


def _dicts(shape, k, rng):
    return [np.stack([random_orthonormal(m, rng) for _ in range(k)]) for m in shape]


def _case(shape, seed):
    """Three random dictionaries, five random points and their codes at τ = 7 (float64)."""
    rng = np.random.default_rng(seed)
    dicts = _dicts(shape, 3, rng)
    x = rng.standard_normal((5, *shape))
    return rng, dicts, x, sparse_code(x, dicts, tau=7, dtype=np.float64)


@pytest.mark.parametrize("shape", SHAPES)
def test_z_from_codes_equals_dense_partial_projections(shape):
    _, dicts, x, codes = _case(shape, 20)
    for mode in range(len(shape)):
        dense = cross_products(x, codes, dicts, mode, np.float64)
        np.testing.assert_allclose(
            sparse_cross_products(x, codes, dicts, mode, np.float64), dense, atol=1e-12
        )
        # the definition, Z = Σ_i [P_i]_(n) [Ŝ_i]_(n)ᵀ, for the first point
        k = codes.membership[0]
        mats = [d[k] for d in dicts]
        p = project(x[:1], mats, skip=mode)[0]
        f = mode_fibres(x[0], mats, codes.point(0)[0], mode)
        loc, val = codes.point(0)
        ref = unfold(p, mode) @ unfold(codes.dense(0), mode).T
        got = np.zeros_like(ref)
        np.add.at(got.T, loc[:, mode], f * val[:, None])
        np.testing.assert_allclose(got, ref, atol=1e-12)


@pytest.mark.parametrize("shape", SHAPES)
def test_code_step_equals_sparse_code_and_yields_two_modes(shape):
    rng, dicts, x, ref = _case(shape, 21)
    got = code_step(x, dicts, 7, dtype=np.float64)
    for name in ("membership", "counts", "values", "locations", "errors"):
        assert np.array_equal(getattr(got.codes, name), getattr(ref, name)), name
    assert np.array_equal(got.ranking[:, 0], ref.membership)
    mode_b, mode_a = pair_modes(shape)
    np.testing.assert_allclose(got.z_last, cross_products(x, ref, dicts, mode_b, np.float64))
    if mode_a is not None:
        # H of the pair gives Z of mode a for any new U_b: Gauss–Seidel after updating b
        new = [d.copy() for d in dicts]
        new[mode_b] = _dicts([shape[mode_b]], 3, rng)[0]
        za = cross_products(x, ref, new, mode_a, np.float64)
        for k in range(3):
            np.testing.assert_allclose(
                pair_cross_products(got.pair[k], new[mode_b][k]), za[k], atol=1e-12
            )
    # batches combine to the whole
    parts = [code_step(x[s], dicts, 7, dtype=np.float64) for s in (slice(0, 2), slice(2, 5))]
    whole = BatchCoding.combine(parts)
    assert np.array_equal(whole.codes.values, got.codes.values)
    np.testing.assert_allclose(whole.z_last, got.z_last, atol=1e-12)


def test_code_step_candidates_pick_the_best_tried():
    rng = np.random.default_rng(22)
    shape = (3, 3, 6, 6)
    dicts = _dicts(shape, 4, rng)
    x = rng.standard_normal((6, *shape))
    full = code_step(x, dicts, 5, dtype=np.float64)
    best2 = code_step(x, dicts, 5, dtype=np.float64, candidates=full.ranking[:, :2])
    assert np.array_equal(best2.codes.membership, full.codes.membership)
    assert np.array_equal(best2.codes.errors, full.codes.errors)
    # without the best one, the point goes to the best of those tried
    worse = code_step(x, dicts, 5, dtype=np.float64, candidates=full.ranking[:, 1:3])
    assert np.array_equal(worse.codes.membership, full.ranking[:, 1])
    assert np.all(worse.codes.errors >= full.codes.errors)
    with pytest.raises(BTFInputError, match="candidates"):
        code_step(x, dicts, 5, candidates=np.full((6, 1), 4))


FIT = dict(n_dictionaries=3, tau=8, tol=0, dtype="float64", random_state=1, progress=False)


@pytest.mark.parametrize("candidates,every", [(1, 0), (1, 3), (2, 0), (2, 4)])
def test_objective_never_increases_with_candidates(candidates, every):
    x = _mixture(10)
    ens = DictionaryEnsemble(
        max_iter=8, candidates=candidates, full_pass_every=every, init="random", **FIT
    ).fit(x)
    obj = np.array(ens.objective_)
    assert len(obj) == 9 and len(ens.passes_) == 9
    assert np.all(np.diff(obj) <= 1e-12 * obj[0])
    assert obj[-1] < obj[0]
    assert "partial" in ens.passes_
    if every:
        for it in range(every, 8, every):
            assert ens.passes_[it] == "full"
    # the final memberships come from a full pass: the exhaustive coding of the final model
    assert ens.passes_[-1] == "full"
    assert np.array_equal(ens.transform(x).membership, ens.membership_)


@pytest.mark.parametrize("candidates", [3, 5])
def test_candidates_k_equals_the_exhaustive_reference(candidates):
    x = _mixture(11)
    fast = DictionaryEnsemble(max_iter=5, candidates=candidates, **FIT).fit(x)
    ref = DictionaryEnsemble(max_iter=5, candidates=3, update="projections", **FIT).fit(x)
    assert fast.passes_ == ["full"] * 6
    np.testing.assert_allclose(fast.objective_, ref.objective_, rtol=1e-10)
    assert np.array_equal(fast.membership_, ref.membership_)
    for a, b in zip(fast.dictionaries_, ref.dictionaries_, strict=True):
        np.testing.assert_allclose(a, b, atol=1e-8)


def test_interrupted_training_resumes_to_the_same_result(tmp_path):
    x = _mixture(12)
    kw = dict(max_iter=6, candidates=1, full_pass_every=3, **FIT)
    whole = DictionaryEnsemble(**kw).fit(x)
    assert whole.passes_[1:] == ["partial", "partial", "full", "partial", "partial", "full"]

    class Interrupted(DictionaryEnsemble):
        def _save_checkpoint(self, state):
            super()._save_checkpoint(state)
            if state.iteration == 2:  # after a partial pass: the candidates must survive
                raise KeyboardInterrupt

    ck = tmp_path / "ck.npz"
    with pytest.raises(KeyboardInterrupt):
        Interrupted(checkpoint=ck, **kw).fit(x)
    resumed = DictionaryEnsemble(checkpoint=ck, **kw).fit(x)
    assert resumed.passes_ == whole.passes_
    np.testing.assert_allclose(resumed.objective_, whole.objective_, rtol=1e-12)
    for a, b in zip(resumed.dictionaries_, whole.dictionaries_, strict=True):
        np.testing.assert_allclose(a, b, atol=1e-12)
    with pytest.raises(BTFInputError, match="other training parameters"):
        DictionaryEnsemble(checkpoint=ck, **{**kw, "candidates": 2}).fit(x)
    # resumed with fewer iterations than the checkpoint holds: still a full final pass
    ck2 = tmp_path / "ck2.npz"
    with pytest.raises(KeyboardInterrupt):
        Interrupted(checkpoint=ck2, **kw).fit(x)
    short = DictionaryEnsemble(checkpoint=ck2, **{**kw, "max_iter": 1}).fit(x)
    assert short.n_iter_ == 2 and short.passes_[-1] == "full"
    assert np.array_equal(short.transform(x).membership, short.membership_)


def test_tolerance_is_confirmed_by_a_full_pass():
    x = _mixture(15)
    ens = DictionaryEnsemble(
        max_iter=30, candidates=1, full_pass_every=0, init="random", **{**FIT, "tol": 1e-2}
    ).fit(x)
    assert ens.n_iter_ < 30
    # a partial pass met the tolerance but the full pass that checked it moved memberships
    # enough to go on; the run stopped on a full pass that met it
    assert "full" in ens.passes_[1:-1]
    assert ens.passes_[-1] == "full"
    obj = ens.objective_
    assert (obj[-2] - obj[-1]) / obj[-2] < 1e-2
    assert np.array_equal(ens.transform(x).membership, ens.membership_)


def test_fast_trainer_parameter_errors():
    x = _mixture(14, n=6)
    for kw, match in (
        ({"candidates": 0}, "candidates"),
        ({"full_pass_every": -1}, "full_pass_every"),
        ({"update": "svd"}, "update"),
    ):
        with pytest.raises(BTFInputError, match=match):
            DictionaryEnsemble(**kw).fit(x)


def test_train_records_the_coding_schedule(tmp_path, capsys):
    """The model file records the candidates, the full-pass period and each pass's kind."""
    from sparsebtf.cli.main import main
    from sparsebtf.storage import load_model

    out = tmp_path / "m.h5"
    rc = main(["train", "synth:wood:8:1:tiny13", "synth:felt:8:2:tiny13", "-o", str(out),
               "--patch", "4", "--dicts", "3", "--tau-train", "8,4,4", "--sample", "1",
               "--iters", "4", "--tol", "0", "--candidates", "2", "--full-pass-every", "2",
               "--json"])
    assert rc == 0
    model = load_model(out)
    assert model.params["candidates"] == 2 and model.params["full_pass_every"] == 2
    for t in model.training.values():
        assert t["passes"] == ["full", "partial", "full", "partial", "full"]
        assert np.all(np.diff(t["objective"]) <= 1e-9 * t["objective"][0])
    capsys.readouterr()
    assert main(["train", "synth:wood:8:1:tiny13", "-o", str(tmp_path / "x.h5"),
                 "--patch", "4", "--full-pass-every", "-1"]) == 2
    assert "--full-pass-every" in capsys.readouterr().err


def test_reseeded_dictionary_is_tried_by_every_point_in_the_next_pass(monkeypatch):
    import sparsebtf.learning.partitions as partitions

    widths = []
    real = partitions.code_step

    def spy(batch, dicts, tau, eps, dtype, candidates=None, sums=None):
        widths.append(None if candidates is None else candidates.shape[1])
        return real(batch, dicts, tau, eps, dtype, candidates, sums)

    monkeypatch.setattr(partitions, "code_step", spy)
    x = _mixture(16, n=12)
    ens = DictionaryEnsemble(
        n_dictionaries=6, max_iter=3, candidates=1, full_pass_every=0, init="random",
        **{k: v for k, v in FIT.items() if k != "n_dictionaries"},
    ).fit(x)
    assert ens.passes_ == ["full", "partial", "partial", "full"]
    # the initial full pass left dictionaries empty: re-seeded, then tried by every point
    n_batches = -(-len(x) // 4)
    first_partial = widths[n_batches : 2 * n_batches]
    assert all(w is not None and w > 1 for w in first_partial)
    assert widths[2 * n_batches : 3 * n_batches] == [1] * n_batches
    assert np.all(np.diff(ens.objective_) <= 1e-12 * ens.objective_[0])

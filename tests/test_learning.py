import numpy as np
import pytest

from sparsebtf.errors import BTFInputError
from sparsebtf.learning.coding import (
    SparseCodes,
    reconstruct_points,
    sparse_code,
    sparse_code_levels,
    topk_abs,
)
from sparsebtf.learning.ensemble import (
    DictionaryEnsemble,
    cross_products,
    procrustes,
    random_orthonormal,
)
from sparsebtf.learning.tensor import fold, mode_dot, multi_mode_dot, project, reconstruct, unfold


def test_unfold_fold_mode_dot():
    rng = np.random.default_rng(0)
    x = rng.standard_normal((3, 4, 5))
    for mode in range(3):
        assert np.array_equal(fold(unfold(x, mode), mode, x.shape), x)
        u = rng.standard_normal((2, x.shape[mode]))
        y = mode_dot(x, u, mode)
        # definition: every mode-n fibre multiplied by U
        assert np.allclose(unfold(y, mode), u @ unfold(x, mode))
    with pytest.raises(ValueError, match="does not fit mode"):
        mode_dot(x, np.ones((2, 7)), 1)


def test_project_and_reconstruct_are_inverse():
    rng = np.random.default_rng(1)
    shape = (3, 4, 6, 5)
    mats = [random_orthonormal(m, rng) for m in shape]
    x = rng.standard_normal((2, *shape))
    s = project(x, mats)
    assert np.allclose(s[0], multi_mode_dot(x[0], mats, transpose=True))
    assert np.allclose(reconstruct(s, mats), x)
    # Parseval
    assert np.allclose((s**2).sum(axis=(1, 2, 3, 4)), (x**2).sum(axis=(1, 2, 3, 4)))


def test_topk_abs_matches_full_sort():
    rng = np.random.default_rng(2)
    for n, k in [(100000, 64), (5000, 885), (30, 30), (10, 50)]:
        c = rng.standard_normal(n)
        c[::7] = np.round(c[::7], 1)  # ties
        got = topk_abs(c, k)
        ref = np.lexsort((np.arange(n), -np.abs(c)))[: min(k, n)]
        assert np.array_equal(got, ref)


def _householder_to(x: np.ndarray, s: np.ndarray) -> np.ndarray:
    """An orthogonal U with Uᵀx = s (needs ‖s‖ = ‖x‖)."""
    v = x - s
    if np.allclose(v, 0):
        return np.eye(x.size)
    return np.eye(x.size) - 2 * np.outer(v, v) / (v @ v)


def _ensemble_for(x: np.ndarray, targets: list[np.ndarray]) -> list[np.ndarray]:
    mats = []
    for s in targets:
        s = s / np.linalg.norm(s) * np.linalg.norm(x)
        mats.append(_householder_to(x, s))
    return [np.stack(mats)]


def test_coding_rule_sparsest_wins():
    rng = np.random.default_rng(3)
    x = rng.standard_normal(16)
    dense = np.r_[np.ones(5), np.zeros(11)]  # needs 5 coefficients
    sparse = np.r_[np.ones(2) * 3, 1e-4 * np.ones(14)]  # needs 2
    dicts = _ensemble_for(x, [dense, sparse])
    codes = sparse_code(x[None], dicts, tau=8, eps=1e-3, dtype=np.float64)
    assert codes.membership[0] == 1 and codes.counts[0] == 2


def test_coding_rule_tie_goes_to_least_error():
    rng = np.random.default_rng(4)
    x = rng.standard_normal(16)
    worse = np.r_[3.0, 3.0, 0.02 * np.ones(14)]  # count 2, larger residual
    better = np.r_[3.0, 3.0, 0.001 * np.ones(14)]  # count 2, smaller residual
    dicts = _ensemble_for(x, [worse, better])
    e = np.linalg.norm(x) ** 2
    # threshold between: both need exactly 2 coefficients
    r_worse = (0.02**2 * 14) / (9 + 9 + 0.02**2 * 14) * e / 16
    codes = sparse_code(x[None], dicts, tau=8, eps=r_worse * 1.5, dtype=np.float64)
    assert codes.counts[0] == 2
    assert codes.membership[0] == 1  # the release would keep the first (0)


def test_coding_rule_capped_goes_to_least_error():
    rng = np.random.default_rng(5)
    x = rng.standard_normal(16)
    a = np.linspace(1, 0.5, 16)
    b = np.r_[np.linspace(3, 2, 4), np.linspace(0.4, 0.1, 12)]
    dicts = _ensemble_for(x, [a, b])
    codes = sparse_code(x[None], dicts, tau=4, eps=1e-12, dtype=np.float64)
    assert codes.counts[0] == 4 and codes.membership[0] == 1


def test_parseval_error_and_sorted_values():
    rng = np.random.default_rng(6)
    shape = (2, 3, 5, 4)
    dicts = [np.stack([random_orthonormal(m, rng) for _ in range(3)]) for m in shape]
    x = rng.standard_normal((5, *shape))
    codes = sparse_code(x, dicts, tau=20, eps=0.0, dtype=np.float64)
    rec = reconstruct_points(codes, dicts)
    size = np.prod(shape)
    # error of the kept subset = ‖X‖² − Σ kept², per entry
    assert np.allclose(codes.errors * size, ((x - rec) ** 2).sum(axis=(1, 2, 3, 4)))
    for i in range(5):
        _, v = codes.point(i)
        assert np.all(np.diff(np.abs(v)) <= 0)
    # membership is the least error at the cap
    for i in range(5):
        errs = []
        for k in range(3):
            s = project(x[i : i + 1], [d[k] for d in dicts]).ravel()
            errs.append(((x[i] ** 2).sum() - np.sort(s**2)[-20:].sum()) / size)
        assert codes.membership[i] == int(np.argmin(errs))


def test_levels_equal_separate_calls_and_truncation():
    rng = np.random.default_rng(7)
    shape = (2, 2, 5, 5)
    dicts = [np.stack([random_orthonormal(m, rng) for _ in range(2)]) for m in shape]
    x = rng.standard_normal((3, *shape))
    lv = sparse_code_levels(x, dicts, [5, 12], eps=1e-3, dtype=np.float64)
    for codes, tau in zip(lv, [5, 12], strict=True):
        ref = sparse_code(x, dicts, tau, 1e-3, np.float64)
        assert np.array_equal(codes.membership, ref.membership)
        assert np.array_equal(codes.locations, ref.locations)
        assert np.allclose(codes.values, ref.values)
    big = lv[1]
    small = big.truncate(4)
    assert small.nnz == 12
    for i in range(3):
        loc_b, val_b = big.point(i)
        loc_s, val_s = small.point(i)
        assert np.array_equal(loc_s, loc_b[:4]) and np.array_equal(val_s, val_b[:4])
    rec = reconstruct_points(small, dicts)
    assert np.allclose(small.errors * 100, ((x - rec) ** 2).sum(axis=(1, 2, 3, 4)), rtol=1e-5)


def test_sparse_code_bad_input():
    dicts = [np.stack([np.eye(3)]), np.stack([np.eye(4)])]
    with pytest.raises(BTFInputError, match="2 modes but the ensemble has 1"):
        sparse_code(np.zeros((1, 3, 4)), dicts[:1], 2)
    with pytest.raises(BTFInputError, match="do not fit mode size 5"):
        sparse_code(np.zeros((1, 3, 5)), dicts, 2)
    with pytest.raises(BTFInputError, match="tau must be >= 1"):
        sparse_code(np.zeros((1, 3, 4)), dicts, 0)
    with pytest.raises(BTFInputError, match="counts"):
        SparseCodes(
            (3,), np.zeros(1, int), np.array([2]), np.zeros(1), np.zeros((1, 1), int), np.zeros(1)
        )


def test_procrustes_maximises_trace():
    rng = np.random.default_rng(8)
    z = rng.standard_normal((6, 6))
    u = procrustes(z)
    assert np.allclose(u.T @ u, np.eye(6))
    best = np.trace(u.T @ z)
    for _ in range(50):
        q = random_orthonormal(6, rng)
        assert np.trace(q.T @ z) <= best + 1e-9


def test_cross_products_match_dense_formula():
    rng = np.random.default_rng(9)
    shape = (2, 3, 4, 3)
    dicts = [np.stack([random_orthonormal(m, rng) for _ in range(2)]) for m in shape]
    x = rng.standard_normal((4, *shape))
    codes = sparse_code(x, dicts, tau=6, dtype=np.float64)
    for mode in range(4):
        z = cross_products(x, codes, dicts, mode, np.float64)
        ref = np.zeros_like(z)
        for i in range(4):
            k = codes.membership[i]
            p = project(x[i : i + 1], [d[k] for d in dicts], skip=mode)[0]
            ref[k] += unfold(p, mode) @ unfold(codes.dense(i), mode).T
        assert np.allclose(z, ref)


def _mixture(seed: int, n: int = 48, shape=(3, 3, 6, 6)):
    rng = np.random.default_rng(seed)
    bases = [[random_orthonormal(m, rng) for m in shape] for _ in range(3)]
    out = []
    for i in range(n):
        s = np.zeros((1, *shape))
        s.reshape(-1)[rng.choice(np.prod(shape), 8, replace=False)] = rng.standard_normal(8) * 3
        out.append(reconstruct(s, bases[i % 3])[0] + 0.02 * rng.standard_normal(shape))
    return np.array(out)


@pytest.mark.parametrize("init", ["points", "random"])
def test_objective_never_increases(init):
    x = _mixture(10)
    ens = DictionaryEnsemble(
        n_dictionaries=3,
        tau=8,
        max_iter=8,
        tol=0,
        init=init,
        dtype="float64",
        random_state=1,
        progress=False,
    ).fit(x)
    obj = np.array(ens.objective_)
    assert len(obj) == 9
    assert np.all(np.diff(obj) <= 1e-12 * obj[0])
    assert obj[-1] < obj[0]
    for d in ens.dictionaries_:
        for k in range(3):
            assert np.allclose(d[k].T @ d[k], np.eye(d.shape[1]), atol=1e-10)
    # ordered by use
    assert np.all(np.diff(ens.counts_) <= 0) and ens.counts_.sum() == len(x)
    assert np.array_equal(np.bincount(ens.membership_, minlength=3), ens.counts_)
    codes = ens.transform(x)
    assert np.allclose(ens.inverse_transform(codes).shape, x.shape)


def test_training_is_seeded_and_resumable(tmp_path):
    x = _mixture(11)
    kw = dict(n_dictionaries=3, tau=8, tol=0, dtype="float64", random_state=2, progress=False)
    full = DictionaryEnsemble(max_iter=4, **kw).fit(x)
    again = DictionaryEnsemble(max_iter=4, **kw).fit(x)
    assert all(
        np.array_equal(a, b) for a, b in zip(full.dictionaries_, again.dictionaries_, strict=True)
    )
    # Extending a finished run: with every pass full (candidates = K) the schedule does not
    # depend on max_iter, so 2 + 2 iterations equal 4 (an interrupted run with partial passes:
    # test_training_steps.py).
    kw["candidates"] = 3
    full = DictionaryEnsemble(max_iter=4, **kw).fit(x)
    ck = tmp_path / "ck.npz"
    DictionaryEnsemble(max_iter=2, checkpoint=ck, **kw).fit(x)
    resumed = DictionaryEnsemble(max_iter=4, checkpoint=ck, **kw).fit(x)
    assert np.allclose(resumed.objective_, full.objective_)
    assert all(
        np.allclose(a, b) for a, b in zip(full.dictionaries_, resumed.dictionaries_, strict=True)
    )
    with pytest.raises(BTFInputError, match="other training parameters"):
        DictionaryEnsemble(max_iter=4, checkpoint=ck, **{**kw, "tau": 9}).fit(x)


def test_empty_dictionary_is_reseeded():
    x = _mixture(12, n=12)
    ens = DictionaryEnsemble(
        n_dictionaries=6, tau=8, max_iter=3, tol=0, init="random", dtype="float64", progress=False
    ).fit(x)
    assert np.all(np.diff(ens.objective_) <= 1e-12)
    assert (ens.counts_ > 0).sum() >= 2


def test_ensemble_parameter_errors():
    x = _mixture(13, n=6)
    with pytest.raises(BTFInputError, match="n_dictionaries"):
        DictionaryEnsemble(n_dictionaries=0).fit(x)
    with pytest.raises(BTFInputError, match="init"):
        DictionaryEnsemble(init="kmeans").fit(x)
    with pytest.raises(BTFInputError, match="not fitted"):
        DictionaryEnsemble().transform(x)


def test_prefetch_keeps_order_and_reraises():
    from sparsebtf._threads import parallel_map, prefetch

    assert list(prefetch(iter(range(50)), depth=2)) == list(range(50))

    def broken():
        yield 1
        raise ValueError("producer failed at item 2")

    it = prefetch(broken())
    assert next(it) == 1
    with pytest.raises(ValueError, match="producer failed"):
        next(it)
    assert list(parallel_map(lambda v: v * v, range(10))) == [v * v for v in range(10)]

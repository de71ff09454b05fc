"""The coder's projections into reused buffers (issue 36): the same values, bit for bit, as
:func:`project`, hence the same codes."""

import numpy as np
import pytest

from sparsebtf.learning import coding
from sparsebtf.learning.codes import topk_abs
from sparsebtf.learning.ensemble import random_orthonormal
from sparsebtf.learning.tensor import project, project_into


def ensemble(sizes, k, seed, dtype=np.float32):
    rng = np.random.default_rng(seed)
    return [np.stack([random_orthonormal(m, rng) for _ in range(k)]).astype(dtype)
            for m in sizes]  # fmt: skip


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_project_into_is_project_bit_for_bit(dtype):
    rng = np.random.default_rng(0)
    sizes = (4, 4, 13, 11)
    mats = [d[0] for d in ensemble(sizes, 1, 1, dtype)]
    bufs = [np.full(2 * int(np.prod(sizes)), np.nan, dtype) for _ in range(2)]  # stale NaN
    for b in (1, 2):
        x = rng.standard_normal((b, *sizes)).astype(dtype)
        got = project_into(x, mats, bufs)
        assert got.shape == (b, *sizes) and np.array_equal(got, project(x, mats))


def test_topk_abs_with_scratch_is_the_same():
    c = np.random.default_rng(2).standard_normal(5000).astype(np.float32)
    scratch = np.full(6000, np.inf, np.float32)
    assert np.array_equal(topk_abs(c, 37, scratch=scratch), topk_abs(c, 37))


@pytest.mark.parametrize("candidates", [None, 2])
def test_codes_equal_those_of_fresh_projections(monkeypatch, candidates):
    dicts = ensemble((4, 4, 13, 13), 3, 3)
    x = np.random.default_rng(4).standard_normal((6, 4, 4, 13, 13)).astype(np.float32)
    new = coding.sparse_code_levels(x, dicts, [40, 300], 1e-3, candidates=candidates)
    # the coder before: a fresh array per mode (project), a fresh |s| (no scratch)
    monkeypatch.setattr(coding, "project_into", lambda b, m, bufs: project(b, m))
    monkeypatch.setattr(coding, "topk_abs", lambda s, k, scratch=None: topk_abs(s, k))
    old = coding.sparse_code_levels(x, dicts, [40, 300], 1e-3, candidates=candidates)
    for a, b in zip(new, old, strict=True):
        for f in ("membership", "counts", "values", "locations", "errors"):
            assert np.array_equal(getattr(a, f), getattr(b, f)), f

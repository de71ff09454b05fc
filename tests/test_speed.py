"""Table 1's fast local reconstruction: decode_speed's rates and what its lookups return."""

from __future__ import annotations

import numpy as np
import pytest

from sparsebtf.codec import encode
from sparsebtf.errors import BTFInputError
from sparsebtf.evaluation.speed import decode_speed, random_queries, single_value_lookup
from sparsebtf.runtime import coded_btf_view, kernels

from .conftest import smooth_btf, tiny_model


@pytest.fixture(scope="module")
def decoded():
    return coded_btf_view(encode(smooth_btf(9), tiny_model(), tau=(40, 8, 8), eps=0.0,
                                 progress=False))  # fmt: skip


class QueryBTF:
    """A stand-in for a neural reconstruction: ``query`` of four index arrays → (n, 3)."""

    def __init__(self, btf):
        self.btf = btf
        self.calls = 0
        self.shape = btf.shape

    def query(self, rows, cols, lights, views):
        self.calls += 1
        return self.btf.data[rows, cols, lights, views]


def test_decode_speed_rates_and_paths(decoded):
    ref = smooth_btf(9)
    q = QueryBTF(ref)
    got = decode_speed({"sparse": decoded, "neural": q, "dense": ref}, batch=512,
                       seconds=0.02, seed=3)  # fmt: skip
    s = got["sparse"]
    assert s["path"].startswith("RuntimeBTF.evaluate")
    assert s["backend"] == ("numba" if kernels.HAVE_NUMBA else "numpy")
    assert s["batch_sizes"] == [1, 512] and s["threads"] >= 1 and s["seed"] == 3
    assert s["threads_1"] == 1
    for label in ("sparse", "neural"):
        r = got[label]
        assert r["queries_per_second_1"] > 0 and r["queries_per_second_batch"] > 0, label
        assert r["calls_1"] >= 1 and r["seconds_batch"] >= 0.02
        # the rate is what was timed: calls x batch / seconds
        assert r["queries_per_second_batch"] == pytest.approx(
            r["calls_batch"] * 512 / r["seconds_batch"])
    assert got["neural"]["path"] == "QueryBTF.query" and q.calls >= 4  # 2 untimed + timed
    d = got["dense"]
    assert d["path"].startswith("ArrayBTF.read") and d["batch_sizes"] == [1]
    assert d["queries_per_second_1"] > 0 and d["queries_per_second_batch"] is None
    if kernels.HAVE_NUMBA:  # batch 1 ran on one thread, and the setting is restored
        import numba

        assert numba.get_num_threads() == s["threads"]
    with pytest.raises(BTFInputError, match="batch"):
        decode_speed({"x": ref}, batch=0)


def test_sparse_lookup_equals_the_dense_decode(decoded):
    """The timed Eq. 5 lookup returns the decoded BTF's values at the same queries."""
    fn, info = single_value_lookup(decoded)
    assert info["batched"]
    rows, cols, lights, views = random_queries(decoded, 300, seed=1)
    dense = decoded.to_array()
    np.testing.assert_allclose(fn(rows, cols, lights, views),
                               dense[rows, cols, lights, views], rtol=1e-4, atol=1e-6)
    # and the read() path returns the same values one by one
    fn_read, _ = single_value_lookup(smooth_btf(9))
    ref = smooth_btf(9).data
    np.testing.assert_array_equal(fn_read(rows[:20], cols[:20], lights[:20], views[:20]),
                                  ref[rows[:20], cols[:20], lights[:20], views[:20]])
    # queries are seeded
    again = random_queries(decoded, 300, seed=1)
    assert all(np.array_equal(a, b) for a, b in zip(again, (rows, cols, lights, views),
                                                    strict=True))

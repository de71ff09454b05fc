"""The preprocessing passes (points/kernels.py): compiled twins equal the NumPy reference,
the fused forward equals Preprocessor.forward, and the banded, threaded statistics pass
equals a float64 computation whatever its bands, threads and view ranges."""

import numpy as np
import pytest

from sparsebtf import _threads
from sparsebtf.colour import RGB_TO_YUV
from sparsebtf.data.btf import ArrayBTF
from sparsebtf.errors import BTFInputError
from sparsebtf.points import kernels, statistics
from sparsebtf.points.grid import extract, iter_points, stream_points
from sparsebtf.points.preprocessing import Preprocessor
from sparsebtf.points.statistics import (
    combine_statistics,
    gather_statistics,
    statistic_bands,
    statistic_sums,
)

from .conftest import smooth_btf

needs_numba = pytest.mark.skipif(not kernels.HAVE_NUMBA, reason="numba is not installed")
M32 = RGB_TO_YUV.astype(np.float32)


def _values(seed: int = 0, n: int = 7, a: int = 13 * 13) -> np.ndarray:
    """Linear RGB with negatives, zeros and a wide range, (n, a, 3) float32."""
    rng = np.random.default_rng(seed)
    x = np.exp(rng.normal(-2, 2, (n, a, 3))).astype(np.float32)
    x[rng.random(x.shape) < 0.05] = 0
    x[rng.random(x.shape) < 0.05] *= -1
    return x


@needs_numba
def test_log_histogram_equals_the_numpy_twin():
    x = _values(seed=3, n=40)
    x[0, :4, 0] = [1e-14, 1e13, np.float32(1e-12), 0]  # clipped below and above, an edge
    got = {}
    for be in ("numpy", "numba"):
        counts = np.zeros(statistics._N_BINS, np.int64)
        kernels.log_histogram(x, -12, 64, counts, backend=be)
        kernels.log_histogram(x[:5], -12, 64, counts, backend=be)  # adds
        got[be] = counts
    assert np.array_equal(got["numpy"], got["numba"])
    assert got["numpy"].sum() == (x > 0).sum() + (x[:5] > 0).sum()
    assert got["numpy"][0] >= 2 and got["numpy"][-1] >= 2


@needs_numba
def test_compiled_passes_equal_the_numpy_twins_bit_for_bit():
    x = _values()
    rng = np.random.default_rng(1)
    mu = rng.normal(-1, 0.5, (x.shape[1], 3)).astype(np.float32)
    inv = rng.uniform(0.5, 3, (x.shape[1], 3)).astype(np.float32)
    got = {}
    for be in ("numpy", "numba"):
        logs, bad, neg = kernels.log_offset(x, 1e-4, backend=be)
        z = kernels.standardise_log_rgb(logs.copy(), M32, mu, inv, backend=be)
        planar = kernels.standardise_log_rgb(logs, M32, mu, inv, backend=be,
                                             out=np.empty((3, *x.shape[:2]), np.float32))
        # planar output: the in-place values, channel by channel
        assert np.array_equal(planar, np.moveaxis(z, -1, 0))
        acc = (np.zeros((x.shape[1], 3), np.float32), np.zeros((x.shape[1], 3)),
               np.zeros((x.shape[1], 3)), np.full(x.shape[1], -np.inf))  # fmt: skip
        kernels.accumulate_sums(logs[:3], M32, *acc, first=True, backend=be)
        kernels.accumulate_sums(logs[3:], M32, *acc, first=False, backend=be)
        got[be] = (logs, z, *acc, bad, neg)
    assert got["numpy"][-2:] == got["numba"][-2:] == (0, int((x < 0).sum()))
    for a, b in zip(got["numpy"][:-2], got["numba"][:-2], strict=True):
        assert a.dtype == b.dtype and np.array_equal(a, b)


@pytest.mark.parametrize("backend", ["numpy"] + (["numba"] if kernels.HAVE_NUMBA else []))
def test_clamp_offset_counts_non_finite_values(backend):
    x = _values(2)
    x[1, 2, 0], x[3, 4, 2] = np.nan, np.inf
    out = np.empty_like(x)
    bad, _ = kernels.clamp_offset(x, 1e-5, out, backend)
    assert bad == 2
    ok = np.isfinite(x)
    assert np.array_equal(out[ok], np.maximum(x[ok], 0) + np.float32(1e-5))


@pytest.mark.parametrize("mode", ["shared", "per_channel"])
def test_forward_into_equals_forward_to_float32_rounding(mode):
    btf = smooth_btf(5)
    pre = Preprocessor(gather_statistics(btf, mode, log_offset=1e-3))
    rgb = btf.patch(4, 0, 4)
    rgb[0, 1, 2, 3] = -0.5  # counts as 0
    ref = pre.forward(np.maximum(rgb, 0), dtype=np.float64)
    out = np.empty(rgb.shape, np.float32)
    got = pre.forward_into(rgb, out)
    assert got is out
    assert np.max(np.abs(got - ref)) <= 4e-6 * max(1.0, np.abs(ref).max())


def test_forward_into_refuses_nan_with_its_location():
    btf = smooth_btf(5)
    pre = Preprocessor(gather_statistics(btf))
    rgb = btf.patch(4, 0, 4)
    rgb[1, 2, 3, 4, 1] = np.nan
    with pytest.raises(BTFInputError, match=r"m: 1 NaN/Inf values; first at row 5, col 2, light 3"):
        pre.forward_into(rgb, np.empty(rgb.shape, np.float32), "m", (4, 0))


def test_iter_points_float32_equals_the_float64_reference():
    btf = smooth_btf(1)
    pre = Preprocessor(gather_statistics(btf))
    ref = extract(pre.forward(btf.to_array().astype(np.float64)), 4)
    for idx, x in iter_points(btf, pre, patch=4, batch=3):
        assert x.dtype == np.float32
        assert np.max(np.abs(x - ref[idx])) <= 4e-6 * max(1.0, np.abs(ref).max())


def _float64_statistics(btf, eps):
    y = np.log(np.maximum(btf.to_array().astype(np.float64), 0) + eps) @ RGB_TO_YUV.T
    n = btf.height * btf.width
    y = y.reshape(n, *y.shape[2:])
    return y.mean(axis=0), y.std(axis=0, ddof=1)


def test_statistics_equal_a_float64_computation():
    btf = smooth_btf(6, size=8)
    stats = gather_statistics(btf, "per_channel", log_offset=1e-4)
    mean, std = _float64_statistics(btf, 1e-4)
    assert np.allclose(stats.mean, mean, rtol=0, atol=2e-6)
    assert np.allclose(stats.std, std, rtol=2e-5, atol=0)


def _dense_like(btf, hint):
    """The same values with a storage hint (rows, views), as a chunked file announces."""
    out = ArrayBTF(btf.data, btf.lights, btf.views, name=btf.name)
    out.block_hint = hint
    return out


def test_statistic_sums_same_bits_whatever_threads_and_view_ranges(monkeypatch):
    btf = _dense_like(smooth_btf(7, size=8), (2, 4))
    monkeypatch.setattr(statistics, "STATS_READ_BYTES", 12 * 8 * 13 * 4 * 3)  # 3 rows
    assert statistic_bands(btf) == (2, 4)  # whole multiples of the hint's rows
    monkeypatch.setenv("SPARSEBTF_THREADS", "1")
    one = statistic_sums(btf, log_offset=1e-4)
    monkeypatch.setenv("SPARSEBTF_THREADS", "2")
    two = statistic_sums(btf, log_offset=1e-4)
    parts = [statistic_sums(btf, r, 1e-4) for r in [(0, 5), (5, 6), (6, 13)]]
    for attr in ("shift", "s1", "s2", "top"):
        assert np.array_equal(getattr(one, attr), getattr(two, attr))
    a = combine_statistics([one], "shared", 1e-4)
    b = combine_statistics(parts, "shared", 1e-4)
    assert np.array_equal(a.mean, b.mean) and np.array_equal(a.std, b.std)
    assert np.array_equal(a.bound, b.bound)


def test_statistics_read_bounded_bands(monkeypatch):
    """Each read of the pass is a band of rows of a few views, never the whole BTF."""
    btf = _dense_like(smooth_btf(8, size=8), (1, 3))
    monkeypatch.setattr(statistics, "STATS_READ_BYTES", 12 * 8 * 13 * 3 * 2)  # 2 rows
    shapes = []
    read = btf.read

    def spy(*args):
        out = read(*args)
        shapes.append(out.shape)
        return out

    monkeypatch.setattr(btf, "read", spy)
    statistic_sums(btf)
    assert {s[0] for s in shapes} == {2} and max(s[3] for s in shapes) == 3
    assert len(shapes) == 4 * 5  # 4 bands x 5 groups of views (3+3+3+3+1)


def test_ordered_map_keeps_order_and_raises(monkeypatch):
    monkeypatch.setenv("SPARSEBTF_THREADS", "2")
    assert list(_threads.ordered_map(lambda v: v * v, range(7))) == [v * v for v in range(7)]

    def fail(v):
        if v == 3:
            raise ValueError("three")
        return v

    got = []
    with pytest.raises(ValueError, match="three"):
        for v in _threads.ordered_map(fail, range(6)):
            got.append(v)
    assert got == [0, 1, 2]


def test_stream_points_equal_iter_points_through_reused_arrays():
    """Batches written into three arrays in turn (and read on the worker threads) hold the
    values of fresh ones, also the short last batch."""
    btf = smooth_btf(9, size=16)
    pre = Preprocessor(gather_statistics(btf))
    points = np.arange(16)
    fresh = [(i.copy(), x.copy()) for i, x in iter_points(btf, pre, 4, points, batch=3)]
    streamed = [(i.copy(), x.copy()) for i, x in stream_points(btf, pre, 4, points, batch=3)]
    assert len(fresh) == len(streamed) == 6
    for (i, x), (j, y) in zip(fresh, streamed, strict=True):
        assert np.array_equal(i, j) and np.array_equal(x, y)


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_channels_first_batches_hold_the_interleaved_values(dtype):
    """The encoder's planar batches (3, b, p, p, L, V): each channel contiguous, the values of
    the interleaved (b, p, p, L, V, 3) ones, through reused arrays and the short last batch;
    a Preprocessor with its threads' scratch arrays still pickles (Dask tasks)."""
    import pickle

    btf = smooth_btf(9, size=16)
    pre = Preprocessor(gather_statistics(btf))
    points = np.arange(16)
    ref = [x.copy() for _, x in iter_points(btf, pre, 4, points, batch=3, dtype=dtype)]
    if dtype == np.float32:
        got = [x.copy() for _, x in stream_points(btf, pre, 4, points, 3, channels_first=True)]
    else:
        got = [x.copy() for _, x in iter_points(btf, pre, 4, points, batch=3, dtype=dtype,
                                                channels_first=True)]  # fmt: skip
    assert [x.shape for x in got] == [(3, *x.shape[:-1]) for x in ref]
    for x, y in zip(ref, got, strict=True):
        assert y.dtype == dtype and np.array_equal(np.moveaxis(x, -1, 0), y)
    again = pickle.loads(pickle.dumps(pre))
    out = np.empty((3, 4, 4, *btf.shape[2:4]), np.float32)
    again.forward_into(btf.patch(0, 0, 4), out)
    want = pre.forward_into(btf.patch(0, 0, 4), np.empty((4, 4, *btf.shape[2:4], 3), np.float32))
    assert np.array_equal(out, np.moveaxis(want, -1, 0))
    with pytest.raises(BTFInputError, match="three C-contiguous"):
        pre.forward_into(btf.patch(0, 0, 4), np.empty((3, 4, 4, *btf.shape[2:4]))[:, ::1, ::2])

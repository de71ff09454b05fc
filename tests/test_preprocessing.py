import numpy as np
import pytest

from sparsebtf.colour import RGB_TO_YUV, YUV_TO_RGB_RELEASE
from sparsebtf.data.btf import ArrayBTF
from sparsebtf.errors import BTFInputError
from sparsebtf.points.grid import PatchGrid, assemble, extract, iter_points, sample_points
from sparsebtf.points.preprocessing import Preprocessor
from sparsebtf.points.statistics import gather_statistics

from .conftest import smooth_btf


@pytest.mark.parametrize("mode", ["shared", "per_channel"])
def test_round_trip_float64(mode):
    btf = smooth_btf(3)
    stats = gather_statistics(btf, mode)
    pre = Preprocessor(stats)
    x = btf.to_array().astype(np.float64)
    z = pre.forward(x)
    back = pre.inverse(z)
    assert np.max(np.abs(back - x) / np.maximum(np.abs(x), 1e-12)) <= 1e-9


def test_round_trip_float32_documented_level():
    btf = smooth_btf(4)
    pre = Preprocessor(gather_statistics(btf))
    x = btf.to_array()
    back = pre.inverse(pre.forward(x, dtype=np.float32).astype(np.float64))
    assert np.max(np.abs(back - x) / x) < 1e-5


def test_statistics_conventions():
    btf = smooth_btf(5)
    x = btf.to_array().astype(np.float64)
    yuv = np.log(x + 1e-5) @ RGB_TO_YUV.T
    flat = yuv.reshape(-1, 13, 13, 3)
    shared = gather_statistics(btf, "shared")
    mu = flat.mean(axis=(0, 3))
    sd = np.mean(
        [np.sqrt(((flat[..., c] - mu) ** 2).sum(0) / (flat.shape[0] - 1)) for c in range(3)], axis=0
    )
    assert np.allclose(shared.mean[..., 0], mu) and np.allclose(shared.std[..., 0], sd)
    per = gather_statistics(btf, "per_channel")
    assert np.allclose(per.mean, flat.mean(axis=0))
    assert np.allclose(per.std, flat.std(axis=0, ddof=1))
    # standardised per-channel data has zero mean and unit std in every angular image
    # statistics use float32 transforms with float64 accumulators: float32-level accuracy
    z = Preprocessor(per).forward(x).reshape(-1, 13, 13, 3)
    assert np.allclose(z.mean(0), 0, atol=1e-6) and np.allclose(z.std(0, ddof=1), 1, atol=1e-6)


def test_release_inverse_matrix_is_close():
    assert np.abs(YUV_TO_RGB_RELEASE @ RGB_TO_YUV - np.eye(3)).max() < 2e-5


def test_negative_values_clamped_with_warning_and_nan_rejected():
    btf = smooth_btf(6)
    data = btf.data.copy()
    data[0, 0, 0, 0, 0] = -1e-3
    data[1, 1, 2, 3, 1] = -2e-3
    with pytest.warns(UserWarning, match="clamped 2 negative values"):
        gather_statistics(ArrayBTF(data, btf.lights, btf.views, name="neg"))
    data[2, 3, 4, 5, 2] = np.nan
    with pytest.raises(
        BTFInputError, match=r"1 NaN/Inf values; first at row 2, col 3, light 4, view 5"
    ):
        gather_statistics(ArrayBTF(data, btf.lights, btf.views, name="nan"))


def test_patch_numbering_matches_release():
    grid = PatchGrid(40, 30, 10)
    assert grid.n_row_blocks == 4 and grid.n_points == 12
    # point = row_block + n_row_blocks * col_block
    assert int(grid.index(3, 2)) == 3 + 4 * 2
    p, i1, i2 = grid.locate(np.array([37]), np.array([25]))
    assert (int(p[0]), int(i1[0]), int(i2[0])) == (3 + 4 * 2, 7, 5)
    # wrapping (tiling)
    p2, _, _ = grid.locate(np.array([37 + 40]), np.array([25 - 30]))
    assert p2[0] == p[0]


def test_extract_assemble_round_trip():
    rng = np.random.default_rng(0)
    img = rng.standard_normal((20, 30, 2, 3))
    pts = extract(img, 10)
    assert pts.shape == (6, 10, 10, 2, 3)
    grid = PatchGrid(20, 30, 10)
    for p in range(6):
        r0, c0 = grid.origin(p)
        assert np.array_equal(pts[p], img[r0 : r0 + 10, c0 : c0 + 10])
    assert np.array_equal(assemble(pts, 20, 30), img)


def test_iter_points_streams_standardised_points():
    btf = smooth_btf(1)
    pre = Preprocessor(gather_statistics(btf))
    full = pre.forward(btf.to_array().astype(np.float64))
    got = {}
    for idx, x in iter_points(btf, pre, patch=4, batch=3, dtype=np.float64):
        assert x.shape[0] <= 3
        got.update(zip(idx.tolist(), x, strict=True))
    ref = extract(full, 4)
    assert sorted(got) == [0, 1, 2, 3]
    for p in range(4):
        assert np.allclose(got[p], ref[p])


def test_sampling_is_seeded():
    a = sample_points([100, 50], 0.1, seed=3)
    b = sample_points([100, 50], 0.1, seed=3)
    c = sample_points([100, 50], 0.1, seed=4)
    assert [len(ix) for _, ix in a] == [10, 5]
    assert all(np.array_equal(x[1], y[1]) for x, y in zip(a, b, strict=True))
    assert not all(np.array_equal(x[1], y[1]) for x, y in zip(a, c, strict=True))
    with pytest.raises(BTFInputError, match="fraction"):
        sample_points([10], 0.0)


def test_grid_size_errors():
    with pytest.raises(BTFInputError, match=r"not a multiple of the patch size 10.*crop"):
        PatchGrid(45, 40, 10)
    with pytest.raises(BTFInputError, match="standardisation mode"):
        gather_statistics(smooth_btf(0), "global")  # type: ignore[arg-type]

import numpy as np
import pytest

from sparsebtf.data.btf import ArrayBTF, FactorBTF, FunctionBTF
from sparsebtf.data.crop import CroppedBTF
from sparsebtf.data.dense_file import DenseFileBTF, write_dense
from sparsebtf.data.directions import tiny
from sparsebtf.errors import BTFInputError, FileFormatError

from .conftest import smooth_btf


def test_accessors_agree(tmp_path):
    btf = smooth_btf(0, size=10)
    arr = btf.data
    assert btf.shape == (10, 10, 13, 13, 3)
    assert np.array_equal(btf.angular_image(3, 5), arr[:, :, 3, 5])
    assert np.array_equal(btf.view_block(4), arr[:, :, :, 4])
    assert np.array_equal(btf.patch(2, 4, 3), arr[2:5, 4:7])
    assert np.array_equal(btf.abrdf(7, 1), arr[7, 1])
    assert np.array_equal(
        btf.read([1, 8], [0, 9], [2, 12], [5]), arr[np.ix_([1, 8], [0, 9], [2, 12], [5], [0, 1, 2])]
    )

    path = write_dense(tmp_path / "b.h5", btf)
    with DenseFileBTF(path) as f:
        assert f.shape == btf.shape and f.lights.equals(btf.lights)
        assert np.array_equal(f.angular_image(3, 5), arr[:, :, 3, 5])
        assert np.array_equal(f.patch(2, 4, 3), arr[2:5, 4:7])
        assert np.array_equal(
            f.read([1, 8], [0, 9], [2, 12], [5]),
            arr[np.ix_([1, 8], [0, 9], [2, 12], [5], [0, 1, 2])],
        )
        assert np.array_equal(f.to_array(), arr)

    fn = FunctionBTF((10, 10), btf.lights, btf.views, lambda v: arr[:, :, :, v], name="fn")
    assert np.array_equal(fn.region(slice(0, 3), slice(5, 10)), arr[0:3, 5:10])
    crop = CroppedBTF(btf, slice(2, 6), slice(4, 10))
    assert np.array_equal(crop.to_array(), arr[2:6, 4:10])


def test_factor_btf_matches_dense_product():
    rng = np.random.default_rng(0)
    d = tiny(7)
    s = rng.standard_normal((3, 36, 4)) * 0.1
    a = rng.standard_normal((3, 49, 4)) * 0.1
    btf = FactorBTF(s, a, 6, 6, d, d, log_domain=True)
    full = np.stack([np.exp(s[c] @ a[c].T) - 1e-5 for c in range(3)], axis=-1)
    full = full.reshape(6, 6, 7, 7, 3)
    assert np.allclose(btf.to_array(), full, rtol=1e-6)
    assert np.allclose(btf.patch(2, 2, 3), full[2:5, 2:5], rtol=1e-6)


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("log_domain", [True, False])
def test_factor_btf_reads_bit_for_bit_from_its_buffers(dtype, log_domain):
    """Each channel's product goes through a buffer of the reading thread: the values are
    those of a fresh product, read after read, on any thread and after pickling."""
    import pickle
    from concurrent.futures import ThreadPoolExecutor

    rng = np.random.default_rng(3)
    d = tiny(7)
    s = (rng.standard_normal((36, 4)) * 0.1).astype(dtype)  # shared spatial factor
    a = (rng.standard_normal((3, 49, 4)) * 0.1).astype(dtype)
    btf = FactorBTF(s, a, 6, 6, d, d, log_domain=log_domain, log_offset=1e-3)
    ref = np.stack([s @ a[c].T for c in range(3)], axis=-1)
    if log_domain:
        ref = np.exp(ref) - 1e-3
    ref = ref.astype(np.float32).reshape(6, 6, 7, 7, 3)
    assert np.array_equal(btf.to_array(), ref)
    for _ in range(2):  # a smaller read after a larger one reuses the buffer
        assert np.array_equal(btf.patch(1, 2, 3), ref[1:4, 2:5])
    with ThreadPoolExecutor(2) as ex:
        got = list(ex.map(lambda r: btf.patch(r, 0, 2), range(5)))
    assert all(np.array_equal(g, ref[r : r + 2, :2]) for r, g in enumerate(got))
    back = pickle.loads(pickle.dumps(btf))
    assert np.array_equal(back.read([0, 5], [1], slice(None), [0, 3, 6]),
                          ref[[0, 5]][:, [1]][:, :, :, [0, 3, 6]])  # fmt: skip


def test_dense_file_streams_large_btf_lazily(tmp_path):
    # a 400x400x151x151 factor BTF: reading a patch never materialises the whole thing
    from sparsebtf.data.directions import ubo2014

    d = ubo2014()
    rng = np.random.default_rng(1)
    s = rng.standard_normal((400 * 400, 3)).astype(np.float32) * 0.01
    a = rng.standard_normal((151 * 151, 3)).astype(np.float32) * 0.01
    btf = FactorBTF(s, a, 400, 400, d, d, log_domain=True)
    assert btf.n_values * 4 > 40e9
    p = btf.patch(390, 0, 10)
    assert p.shape == (10, 10, 151, 151, 3)
    with pytest.raises(BTFInputError, match="refusing"):
        btf.to_array()


@pytest.mark.parametrize(
    "make, match",
    [
        (lambda d: ArrayBTF(np.zeros((2, 2, 7, 7)), d, d), "rank 5"),
        (lambda d: ArrayBTF(np.zeros((2, 2, 7, 7, 4)), d, d), "3 colour channels"),
        (lambda d: ArrayBTF(np.zeros((2, 2, 6, 7, 3)), d, d), "6 lights but the light table has 7"),
        (lambda d: ArrayBTF(np.zeros((2, 2, 7, 5, 3)), d, d), "5 views but the view table has 7"),
        (
            lambda d: ArrayBTF(np.zeros((2, 2, 7, 7, 3)), d, d).read([5], [0], [0], [0]),
            "row index 5",
        ),
        (lambda d: ArrayBTF(np.zeros((2, 2, 7, 7, 3)), d, d).patch(1, 0, 2), "leaves"),
        (lambda d: FactorBTF(np.zeros((5, 2)), np.zeros((49, 2)), 2, 2, d, d), "expected H\\*W"),
        (lambda d: FactorBTF(np.zeros((4, 2)), np.zeros((49, 3)), 2, 2, d, d), "ranks differ"),
    ],
)
def test_bad_btf_input(make, match):
    with pytest.raises(BTFInputError, match=match):
        make(tiny(7))


def test_dense_file_errors(tmp_path):
    btf = smooth_btf(0, size=4, n_dirs=7)
    bad = btf.data.copy()
    bad[1, 2, 3, 4, 0] = np.nan
    bad[0, 0, 0, 6, 1] = np.inf
    target = tmp_path / "nan.h5"
    with pytest.raises(
        BTFInputError, match=r"2 NaN/Inf values.*first at row 0, col 0, light 0, view 6, channel 1"
    ):
        write_dense(target, ArrayBTF(bad, btf.lights, btf.views, name="nanbtf"))
    assert not target.exists() and not list(tmp_path.iterdir())
    with pytest.raises(FileFormatError, match="no such file"):
        DenseFileBTF(tmp_path / "missing.h5")
    (tmp_path / "junk.h5").write_bytes(b"not hdf5 at all")
    with pytest.raises(FileFormatError, match="not a readable HDF5"):
        DenseFileBTF(tmp_path / "junk.h5")
    import h5py

    with h5py.File(tmp_path / "other.h5", "w") as f:
        f.attrs["format"] = "something-else"
    with pytest.raises(FileFormatError, match="'format' is 'something-else'"):
        DenseFileBTF(tmp_path / "other.h5")
    good = write_dense(tmp_path / "good.h5", btf)
    with h5py.File(good, "a") as f:
        f.attrs["schema_version"] = 99
    with pytest.raises(FileFormatError, match="schema_version 99"):
        DenseFileBTF(good)


def test_write_dense_by_regions_equals_by_views(tmp_path):
    btf = smooth_btf(2, size=24)
    a = write_dense(tmp_path / "a.h5", btf, by="views")
    b = write_dense(tmp_path / "b.h5", btf, by="regions")
    with DenseFileBTF(a) as fa, DenseFileBTF(b) as fb:
        assert np.array_equal(fa.to_array(), fb.to_array())
        assert np.array_equal(fa.to_array(), btf.data)
    with pytest.raises(BTFInputError, match="'views' or 'regions'"):
        write_dense(tmp_path / "c.h5", btf, by="texels")


@pytest.mark.parametrize("hint", [(1, 1), (2, 3), (20, 8)])
@pytest.mark.parametrize("max_bytes", [100, 5000, 10**8])
def test_iter_blocks_covers_every_value_once(hint, max_bytes) -> None:
    rng = np.random.default_rng(4)
    d = tiny(7)
    arr = rng.uniform(0, 1, (5, 6, 7, 7, 3)).astype(np.float32)
    btf = ArrayBTF(arr, d, d)
    btf.block_hint = hint
    blocks = list(btf.iter_blocks(max_bytes))
    assert sum(b.size for b in blocks) == arr.size
    total = sum(float(b.sum(dtype=np.float64)) for b in blocks)
    assert np.isclose(total, arr.sum(dtype=np.float64))
    assert max(b.nbytes for b in blocks) <= max(max_bytes, 12 * 7 * 3)

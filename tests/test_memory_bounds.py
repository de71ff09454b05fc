"""What bounds memory: a dense file's chunk cache and compare()'s tiles."""

import numpy as np

from sparsebtf.data.btf import ArrayBTF
from sparsebtf.data.dense_file import DenseFileBTF, chunk_cache_bytes, write_dense
from sparsebtf.metrics import compare, compare_tile

from .conftest import smooth_btf

UBO = (400, 400, 151, 151, 3)
CHUNK = (20, 20, 8, 8, 3)


def test_chunk_cache_holds_one_tile_of_every_direction(monkeypatch):
    monkeypatch.delenv("SPARSEBTF_MAX_MEMORY_GB", raising=False)
    tile = 20 * 20 * 8 * 8 * 3 * 4 * 19 * 19  # 19 x 19 angular chunks of float32
    assert chunk_cache_bytes(UBO, CHUNK, np.dtype("float32")) == tile
    assert chunk_cache_bytes(UBO, CHUNK, np.dtype("float16")) == tile // 2
    small = chunk_cache_bytes((8, 8, 13, 13, 3), (4, 4, 4, 4, 3), np.dtype("float32"))
    assert small == 2**20  # at least HDF5's default
    monkeypatch.setenv("SPARSEBTF_MAX_MEMORY_GB", "0.5")  # an eighth of the budget at most
    assert chunk_cache_bytes(UBO, CHUNK, np.dtype("float32")) == 2**29 // 8


def test_dense_file_opens_with_its_chunk_cache(tmp_path):
    btf = smooth_btf(2, size=8, n_dirs=13)
    path = write_dense(tmp_path / "m.h5", btf, chunks=(4, 4, 4, 4, 3))
    dense = DenseFileBTF(path)
    want = chunk_cache_bytes(btf.shape, (4, 4, 4, 4, 3), np.dtype("float32"))
    assert dense._ds.id.get_access_plist().get_chunk_cache()[1] == want
    assert np.array_equal(dense.patch(4, 4, 4), btf.patch(4, 4, 4))


def test_compare_tiles_bounded_and_same_metrics():
    assert compare_tile(151 * 151) == 10
    assert compare_tile(13 * 13) >= 100
    ref = smooth_btf(3, size=20, n_dirs=13)
    rng = np.random.default_rng(0)
    noisy = ArrayBTF(ref.data * rng.uniform(0.9, 1.1, ref.data.shape).astype(np.float32),
                     ref.lights, ref.views, name="noisy")  # fmt: skip
    whole = compare(ref, noisy, ssim_images=2, progress=False)
    tiled = compare(ref, noisy, tile=10, ssim_images=2, progress=False)
    for key in ("mse_rgb", "mse_log", "mse_display", "psnr_rgb", "ssim"):
        assert np.isclose(whole[key], tiled[key], rtol=1e-12), key

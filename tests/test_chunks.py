"""Dense files read chunk by chunk with the checksums verified here (issue 36): HDF5's
fletcher32 to the bit, the values of h5py's reads, every chunk verified once, and whatever
this reader does not know left to h5py."""

import h5py
import numpy as np
import pytest

from sparsebtf.data import chunks
from sparsebtf.data.chunks import ChunkReader, fletcher32
from sparsebtf.data.dense_file import DenseFileBTF, write_dense
from sparsebtf.errors import FileFormatError

from .conftest import smooth_btf


@pytest.fixture
def dense(tmp_path):
    """A 12×12 BTF of 13 directions, chunks that do not divide it (edge chunks)."""
    btf = smooth_btf(7, size=12)
    return btf, write_dense(tmp_path / "b.h5", btf, chunks=(5, 4, 6, 5, 3))


def test_fletcher32_is_hdf5s(dense):
    _, path = dense
    with h5py.File(path, "r") as f:
        ds = f["btf"]
        for i in range(ds.id.get_num_chunks()):
            _, raw = ds.id.read_direct_chunk(ds.id.get_chunk_info(i).chunk_offset)
            data = np.frombuffer(raw, np.uint8)
            assert fletcher32(data[:-4]) == int.from_bytes(raw[-4:], "little")
    rng = np.random.default_rng(0)
    for n in (0, 1, 2, 3, 255, 4096, 2 * (1 << 16) + 3):
        x = rng.integers(0, 256, n, dtype=np.uint8)
        assert fletcher32(x) == chunks._fletcher32_numpy(x), n
    # the folds: all zero is 0; sums that are nonzero multiples of 65,535 stay 65,535
    for x in (np.zeros(6, np.uint8), np.full(2 * 65535, 255, np.uint8), np.array([0, 1], np.uint8)):
        assert fletcher32(x) == chunks._fletcher32_numpy(x)
    assert fletcher32(np.full(2 * 65535, 255, np.uint8)) == 0xFFFFFFFF


def test_reads_equal_h5pys(dense):
    btf, path = dense
    rng = np.random.default_rng(1)
    with DenseFileBTF(path) as f, h5py.File(path, "r") as h:
        assert f._chunks is not None and f._chunks.checksum
        assert np.array_equal(f.to_array(), h["btf"][()])
        for _ in range(20):
            sizes = (12, 12, 13, 13)
            lo = rng.integers(0, sizes)
            hi = [int(rng.integers(a + 1, n + 1)) for a, n in zip(lo, sizes, strict=True)]
            box = tuple(slice(int(a), b) for a, b in zip(lo, hi, strict=True))
            assert np.array_equal(f.read(*box), h["btf"][box]), box
        assert np.array_equal(f.patch(8, 8, 4), btf.patch(8, 8, 4))


def test_each_chunk_is_verified_once(dense, monkeypatch):
    _, path = dense
    calls = []
    monkeypatch.setattr(chunks, "fletcher32", lambda d: calls.append(1) or fletcher32(d))
    with DenseFileBTF(path) as f:
        n = f._ds.id.get_num_chunks()
        f._chunks._capacity = 1  # no cache: every read reads its chunks again
        f.to_array()
        f.to_array()
        assert len(calls) == n and f._chunks._verified.all()


def test_a_damaged_chunk_is_left_to_h5py_which_names_it(dense, tmp_path):
    _, path = dense
    with h5py.File(path, "r") as f:
        info = f["btf"].id.get_chunk_info(3)
    raw = bytearray(path.read_bytes())
    raw[info.byte_offset + 17] ^= 4
    bad = tmp_path / "bad.h5"
    bad.write_bytes(bytes(raw))
    box = tuple(slice(o, o + 1) for o in info.chunk_offset)
    with h5py.File(bad, "r") as f:
        reader = ChunkReader.of(f["btf"], 2**20)
        assert reader.read(box) is None and not reader._verified.any()
        whole = tuple(slice(0, n) for n in f["btf"].shape)
        assert reader.read(whole) is None
    with pytest.raises(FileFormatError, match=r"/btf: checksum mismatch"):
        with DenseFileBTF(bad) as b:
            b.to_array()


def test_layouts_it_does_not_know_are_read_by_h5py(tmp_path):
    x = np.random.default_rng(2).random((6, 6, 4, 4, 3), dtype=np.float32)
    with h5py.File(tmp_path / "x.h5", "w") as f:
        zipped = f.create_dataset("gzip", data=x, chunks=(3, 3, 4, 4, 3), compression="gzip")
        big = f.create_dataset("be", data=x.astype(">f4"), chunks=(3, 3, 4, 4, 3))
        plain = f.create_dataset("plain", data=x, chunks=(4, 4, 4, 4, 3))
        part = f.create_dataset("part", shape=x.shape, dtype="<f4", chunks=(3, 3, 4, 4, 3))
        part[:3, :3] = x[:3, :3]  # the other chunks never written
        assert ChunkReader.of(zipped, 2**20) is None and ChunkReader.of(big, 2**20) is None
        reader = ChunkReader.of(plain, 2**20)
        assert reader is not None and not reader.checksum
        box = (slice(1, 6), slice(0, 5), slice(0, 4), slice(1, 3), slice(0, 3))
        assert np.array_equal(reader.read(box), x[box])
        assert ChunkReader.of(part, 2**20).read(box) is None  # h5py gives the fill value

"""Reads of a file whose reader holds a lock of the process (h5py's): the coding loop and the
statistics pass read on one thread, one read after another, while the worker threads compute;
the values are those of reading on the workers (issue 36)."""

import threading

import numpy as np
import pytest

from sparsebtf import _threads
from sparsebtf.data.crop import CroppedBTF
from sparsebtf.data.dense_file import DenseFileBTF, write_dense
from sparsebtf.points import statistics
from sparsebtf.points.grid import iter_points, stream_points
from sparsebtf.points.preprocessing import Preprocessor
from sparsebtf.points.statistics import gather_statistics, statistic_sums

from .conftest import smooth_btf


@pytest.fixture
def dense(tmp_path, monkeypatch):
    """A 12×12 BTF of 13 directions in a dense file with small chunks (several reads per
    band and patch), and two workers whatever the machine."""
    monkeypatch.setattr(_threads, "n_workers", lambda: 2)
    monkeypatch.setattr(statistics, "STATS_READ_BYTES", 1)  # bands of a chunk row
    btf = smooth_btf(7, size=12)
    path = write_dense(tmp_path / "b.h5", btf, chunks=(4, 4, 5, 5, 3))
    with DenseFileBTF(path) as f:
        yield btf, f


class ReadThreads:
    """Records which threads read a BTF's patches and bands."""

    def __init__(self, monkeypatch, cls) -> None:
        self.threads: set[int] = set()
        inner = cls.read

        def read(btf, *args):  # type: ignore[no-untyped-def]
            self.threads.add(threading.get_ident())
            return inner(btf, *args)

        monkeypatch.setattr(cls, "read", read)


def test_dense_files_and_their_crops_read_serially(dense):
    btf, f = dense
    assert f.serial_reads and not btf.serial_reads
    assert CroppedBTF(f, slice(0, 8), slice(4, 12)).serial_reads


def test_coding_reads_on_one_thread_with_the_same_values(dense, monkeypatch):
    btf, f = dense
    pre = Preprocessor(gather_statistics(btf, progress=False))
    reads = ReadThreads(monkeypatch, DenseFileBTF)
    got = [(i.copy(), x.copy()) for i, x in stream_points(f, pre, 4, range(9), batch=4)]
    assert len(reads.threads) == 1 and threading.get_ident() not in reads.threads
    ref = list(iter_points(btf, pre, 4, range(9), batch=4))
    assert len(got) == len(ref) == 3
    for (gi, gx), (ri, rx) in zip(got, ref, strict=True):
        assert np.array_equal(gi, ri) and np.array_equal(gx, rx)


def _sums_on_the_workers(f, monkeypatch, *args, **kwargs):
    with monkeypatch.context() as m:
        m.setattr(DenseFileBTF, "serial_reads", False)
        return statistic_sums(f, *args, **kwargs)


@pytest.mark.parametrize("sample", [False, True])
def test_statistics_read_on_one_thread_with_the_same_sums(dense, monkeypatch, sample):
    _, f = dense
    parallel = _sums_on_the_workers(f, monkeypatch, log_offset=0.01, sample=sample)
    reads = ReadThreads(monkeypatch, DenseFileBTF)
    serial = statistic_sums(f, log_offset=0.01, sample=sample)
    assert len(reads.threads) == 1 and threading.get_ident() not in reads.threads
    for name in ("shift", "s1", "s2", "top", "counts"):
        a, b = getattr(serial, name), getattr(parallel, name)
        assert (a is None and b is None) or np.array_equal(a, b), name
    assert (serial.negatives, serial.seen) == (parallel.negatives, parallel.seen)
    # a view range cutting the file's view blocks
    assert np.array_equal(statistic_sums(f, (3, 11), 0.01).s2,
                          _sums_on_the_workers(f, monkeypatch, (3, 11), 0.01).s2)  # fmt: skip
    # one worker: no reading thread
    monkeypatch.setattr(_threads, "n_workers", lambda: 1)
    reads.threads.clear()
    assert np.array_equal(statistic_sums(f, log_offset=0.01).s2, parallel.s2)
    assert reads.threads == {threading.get_ident()}

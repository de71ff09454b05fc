"""A dense file's chunks read directly, their fletcher32 checksums verified here.

h5py reads a hyperslab through HDF5's filter pipeline: each chunk is read, its fletcher32
checksum computed, and the requested part copied out through the hyperslab machinery, all
under h5py's lock for the process. The statistics pass's reading thread, that pass's
critical path, took 2.4 CPU-s that way for a 100×100 dense file (2.8 GB) and takes 1.7 here
(``benchmarks/bench_encode_real.py``). :class:`ChunkReader` reads each chunk's stored bytes
(``read_direct_chunk``), verifies the checksum with a compiled kernel (:func:`fletcher32`,
HDF5's function to the bit) and copies the requested part with NumPy, outside the lock.

Every chunk is verified the first time the open file reads it, as HDF5 verifies a chunk when
it enters its cache: the coding pass, which reads each chunk again after the statistics pass
(twice, as a tile's data points come in two columns), then only copies. A layout this reader
does not know (compression, other filters, another dtype) is left to h5py, as is any chunk
it cannot read or whose checksum differs: h5py then reads it, raising its checksum error (or
accepting the byte-swapped checksums of HDF5 1.6.0–1.6.2).
"""

from __future__ import annotations

import itertools
import math
import threading
from collections import OrderedDict

import h5py
import numpy as np

from .._numba import HAVE_NUMBA
from .._numba import numba as _nb

__all__ = ["ChunkReader", "fletcher32"]

#: HDF5's filter identifier of the fletcher32 checksum (H5Z_FILTER_FLETCHER32).
FLETCHER32 = 3
#: Words summed between reductions modulo 65,535: the weighted sum of a block stays below
#: 2^16 · 65,535 · 2^16 < 2^63.
_BLOCK = 1 << 16


def _fletcher32_numpy(data: np.ndarray) -> int:
    words = data[: data.size // 2 * 2].view(">u2")
    s1 = s2 = 0
    for start in range(0, words.size, _BLOCK):
        w = words[start : start + _BLOCK].astype(np.int64)
        m = w.size
        # over a block, s2 gains m·s1 + Σ (m − i)·w_i (each word adds the running s1)
        t2 = int(np.dot(np.arange(m, 0, -1, dtype=np.int64), w))
        s2 = (s2 + m * s1 + t2) % 65535
        s1 = (s1 + int(w.sum())) % 65535
    if data.size % 2:
        s1 = (s1 + (int(data[-1]) << 8)) % 65535
        s2 = (s2 + s1) % 65535
    return _fold(s1, s2, bool(np.any(data)))


def _fold(s1: int, s2: int, nonzero: bool) -> int:
    """HDF5's 16-bit sums: its folds keep the residue modulo 65,535 and are 0 only for an
    all-zero input, so a nonzero multiple of 65,535 is 65,535."""
    if not nonzero:
        return 0
    return (((s2 - 1) % 65535 + 1) << 16) | ((s1 - 1) % 65535 + 1)


if HAVE_NUMBA:
    assert _nb is not None

    @_nb.njit(cache=True, nogil=True)
    def _fletcher32_sums(words):  # pragma: no cover - compiled
        """(sum1, sum2, any nonzero) of little-endian-loaded 16-bit words (each byte-swapped
        here: HDF5 reads them big-endian)."""
        n = words.size
        s1 = np.int64(0)
        s2 = np.int64(0)
        nonzero = False
        for start in range(0, n, _BLOCK):
            end = min(n, start + _BLOCK)
            t1 = np.int64(0)
            t2 = np.int64(0)
            for i in range(start, end):  # no dependence between words: vectorised (5 GB/s)
                x = np.int64(words[i])
                w = ((x & 0xFF) << 8) | (x >> 8)
                t1 += w
                t2 += (end - i) * w
            s2 = (s2 + (end - start) * s1 + t2) % 65535
            s1 = (s1 + t1) % 65535
            nonzero = nonzero or t1 != 0
        return s1, s2, nonzero


def fletcher32(data: np.ndarray) -> int:
    """HDF5's fletcher32 checksum (``H5_checksum_fletcher32``) of the bytes ``data`` (a 1D
    uint8 array): sums of big-endian 16-bit words modulo 65,535, (sum2 << 16) | sum1."""
    if not HAVE_NUMBA:
        return _fletcher32_numpy(data)
    even = data.size // 2 * 2
    s1, s2, nonzero = (int(v) for v in _fletcher32_sums(data[:even].view("<u2")))
    if data.size % 2:  # the last byte, as the high byte of a word
        last = int(data[-1]) << 8
        s1 = (s1 + last) % 65535
        s2 = (s2 + s1) % 65535
        nonzero = nonzero or bool(last)
    return _fold(s1, s2, bool(nonzero))


class _Unreadable(Exception):
    """A chunk this reader leaves to h5py (not allocated, a checksum that differs)."""


class ChunkReader:
    """Hyperslabs of a chunked, uncompressed little-endian float32 dataset whose only filter
    is fletcher32 (or none), from its chunks' stored bytes; the last ``cache`` chunks read
    are kept (the chunks of a spatial tile: a tile's data points then read each chunk
    once)."""

    def __init__(self, ds: h5py.Dataset, cache: int, checksum: bool) -> None:
        self._ds = ds
        self.shape = tuple(int(s) for s in ds.shape)
        self.chunks = tuple(int(c) for c in ds.chunks)
        self._nbytes = math.prod(self.chunks) * 4  # a chunk's float32 values, checksum aside
        self.checksum = checksum
        grid = [-(-s // c) for s, c in zip(self.shape, self.chunks, strict=True)]
        self._verified = np.zeros(grid, dtype=bool)
        self._cache: OrderedDict[tuple[int, ...], np.ndarray] = OrderedDict()
        self._capacity = max(1, cache)
        self._lock = threading.Lock()

    @classmethod
    def of(cls, ds: h5py.Dataset, cache_bytes: int) -> ChunkReader | None:
        """A reader of ``ds`` keeping about ``cache_bytes`` of chunks, or None when its layout
        is one this reader does not know (h5py reads it)."""
        if ds.chunks is None or ds.dtype != np.dtype("<f4"):
            return None
        plist = ds.id.get_create_plist()
        filters = [plist.get_filter(i)[0] for i in range(plist.get_nfilters())]
        if filters not in ([], [FLETCHER32]):
            return None
        per_chunk = math.prod(ds.chunks) * 4
        return cls(ds, cache_bytes // per_chunk, checksum=bool(filters))

    def read(self, box: tuple[slice, ...]) -> np.ndarray | None:
        """The float32 values of ``box`` (one slice of step 1 per axis), or None where a chunk
        is left to h5py."""
        out = np.empty([s.stop - s.start for s in box], dtype=np.float32)
        ranges = [range(s.start // c, (s.stop - 1) // c + 1) for s, c in
                  zip(box, self.chunks, strict=True)]  # fmt: skip
        try:
            for index in itertools.product(*ranges):
                origin = [i * c for i, c in zip(index, self.chunks, strict=True)]
                chunk = self._chunk(tuple(origin))
                src, dst = [], []
                for o, c, s in zip(origin, self.chunks, box, strict=True):
                    lo, hi = max(o, s.start), min(o + c, s.stop)
                    src.append(slice(lo - o, hi - o))
                    dst.append(slice(lo - s.start, hi - s.start))
                out[tuple(dst)] = chunk[tuple(src)]
        except _Unreadable:
            return None
        return out

    def _chunk(self, origin: tuple[int, ...]) -> np.ndarray:
        with self._lock:
            have = self._cache.get(origin)
            if have is not None:
                self._cache.move_to_end(origin)
                return have
        try:
            mask, raw = self._ds.id.read_direct_chunk(origin)
        except (OSError, KeyError, ValueError, RuntimeError) as e:  # not allocated, unreadable
            raise _Unreadable from e
        data = np.frombuffer(raw, dtype=np.uint8)
        n = self._nbytes
        at = tuple(o // c for o, c in zip(origin, self.chunks, strict=True))
        if self.checksum and not mask & 1:  # bit 0 set: the filter was skipped for this chunk
            if data.size != n + 4:
                raise _Unreadable
            if not self._verified[at]:
                if fletcher32(data[:n]) != int.from_bytes(raw[n:], "little"):
                    raise _Unreadable
                self._verified[at] = True
        elif data.size < n:
            raise _Unreadable
        chunk = data[:n].view("<f4").reshape(self.chunks)
        with self._lock:
            self._cache[origin] = chunk
            while len(self._cache) > self._capacity:
                self._cache.popitem(last=False)
        return chunk

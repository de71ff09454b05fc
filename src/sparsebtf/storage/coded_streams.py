"""Schema-3 coefficient streams: sorted locations as gaps, values in the same order, HDF5's
built-in lossless filters (layout and inverse in ``docs/format.md`` §3).

Per channel and data point the coefficients are stored in increasing column-major linear
location ``l = l1 + m1·l2 + m1·m2·l3 + …`` (MATLAB's ``sub2ind``, the release's index) instead
of decreasing magnitude::

    location_gaps (NNZ,) <u4   first coefficient of a point: l; each next one: l − previous l
                                (> 0: locations are unique within a point)
    values        (NNZ,) <f2   the values in that order (<f4 when one overflows binary16)
    rank          (NNZ,) <u2|<u4   optional: each coefficient's position in its point's
                                magnitude order, written only when that order is not the rule
                                below (codes from before the rule, e.g. an old file converted)

Sorted locations are mostly small gaps, so ``shuffle`` + ``deflate`` packs them to ~5 bits
instead of Table 4's 24; the values stay exact. The reader restores each point's magnitude
order — the order level of detail truncates — by the **magnitude rule**: decreasing
``|stored value|``, ties by increasing ``l``. :func:`canonical_codes` puts codes in that order
(the encoders do, so their files need no ``rank``), hence a schema-3 file decodes to the very
arrays, in the very order, of a schema-2 file of the same codes.
"""

from __future__ import annotations

import warnings
from dataclasses import replace

import h5py
import numpy as np

from .._h5check import checked_dataset, read_array
from .._hdf5 import create_dataset
from .._semantic import stored_dtype
from ..errors import BTFInputError, FileFormatError
from ..learning.coding import SparseCodes
from ..points.preprocessing import Standardization

__all__ = [
    "binary16_statistics",
    "canonical_codes",
    "linear_locations",
    "magnitude_order",
    "read_streams",
    "stored_values",
    "write_streams",
]

_FP16_MAX = float(np.finfo(np.float16).max)


def stored_values(values: np.ndarray, where: str = "") -> np.ndarray:
    """The values as a coded file stores them: binary16 (round to nearest even), or float32
    for a channel with a finite value beyond ±65504 (with a warning naming ``where``)."""
    vals = np.asarray(values)
    dtype = stored_dtype(vals)
    if dtype.itemsize == 4:
        warnings.warn(
            f"{where}: values up to {float(np.max(np.abs(vals))):.4g} overflow binary16; "
            "storing this channel's values in float32",
            stacklevel=3,
        )
    return vals.astype(dtype)


def linear_locations(locations: np.ndarray, mode_sizes: tuple[int, ...]) -> np.ndarray:
    """(NNZ, N) multi-indices → (NNZ,) int64 column-major linear indices ``l``."""
    strides = np.cumprod((1, *mode_sizes[:-1]), dtype=np.int64)
    return np.asarray(locations, dtype=np.int64) @ strides


def _point_ids(counts: np.ndarray) -> np.ndarray:
    return np.repeat(np.arange(counts.size, dtype=np.int64), np.asarray(counts, dtype=np.int64))


def magnitude_order(counts: np.ndarray, values: np.ndarray, linear: np.ndarray) -> np.ndarray:
    """The permutation that puts every point's coefficients in magnitude-rule order:
    point by point, decreasing ``|values|``, ties by increasing ``linear``. (NNZ,) int64."""
    mag = np.abs(np.asarray(values, dtype=np.float64))
    return np.lexsort((linear, -mag, _point_ids(counts)))


def _rule_order_of_sorted(counts: np.ndarray, values: np.ndarray) -> np.ndarray:
    """:func:`magnitude_order` of coefficients already sorted by increasing location within
    each point (the stored order): a stable sort on one integer key, point then decreasing
    magnitude (the IEEE bits of |v| order like |v|), keeps the location order of ties."""
    v = np.abs(np.asarray(values))
    pid = _point_ids(counts)
    if v.dtype.itemsize == 2 and counts.size <= 1 << 16:
        # two stable 16-bit sorts (NumPy radix-sorts them): magnitude, then point
        by_mag = np.argsort(np.uint16(0xFFFF) - v.view(np.uint16), kind="stable")
        return by_mag[np.argsort(pid[by_mag].astype(np.uint16), kind="stable")]
    bits = v.view(np.uint16 if v.dtype.itemsize == 2 else np.uint32).astype(np.int64)
    key = (pid << (8 * v.dtype.itemsize)) - bits
    return np.argsort(key, kind="stable")


def _unravel(lin: np.ndarray, sizes: tuple[int, ...]) -> np.ndarray:
    """(NNZ,) column-major linear indices → (NNZ, N) int32 multi-indices."""
    out = np.empty((lin.size, len(sizes)), dtype=np.int32)
    rest = lin.astype(np.int64)
    for n, m in enumerate(sizes):
        rest, out[:, n] = np.divmod(rest, m)
    return out


def canonical_codes(codes: SparseCodes) -> SparseCodes:
    """``codes`` with each point's coefficients in magnitude-rule order on their stored
    (binary16) values: only ties among equal stored magnitudes move, so any τ prefix keeps
    its error up to rounding. Returns ``codes`` itself when already in that order."""
    if codes.nnz == 0:
        return codes
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        vs = stored_values(codes.values)
    lin = linear_locations(codes.locations, tuple(int(m) for m in codes.mode_sizes))
    order = magnitude_order(codes.counts, vs, lin)
    if np.array_equal(order, np.arange(order.size)):
        return codes
    return SparseCodes(
        codes.mode_sizes, codes.membership, codes.counts, codes.values[order],
        codes.locations[order], codes.errors,
    )  # fmt: skip


def write_streams(g: h5py.Group, c: SparseCodes, where: str) -> None:
    """Write ``location_gaps``, ``values`` (and ``rank`` if needed) of ``c`` into ``g``."""
    sizes = tuple(int(m) for m in c.mode_sizes)
    vals = stored_values(c.values, where)
    lin = linear_locations(c.locations, sizes)
    pid = _point_ids(c.counts)
    by_loc = np.lexsort((lin, pid))
    lin_s = lin[by_loc]
    starts = np.asarray(c.offsets[:-1], dtype=np.int64)[np.asarray(c.counts) > 0]
    gaps = np.diff(lin_s, prepend=0)
    gaps[starts] = lin_s[starts]
    first = np.zeros(lin_s.size, dtype=bool)
    first[starts] = True
    if np.any((gaps <= 0) & ~first):
        i = int(pid[by_loc][np.argmax((gaps <= 0) & ~first)])
        raise BTFInputError(f"{where}: point {i} repeats a location; locations must be unique")
    vals_s = vals[by_loc]
    create_dataset(g, "location_gaps", data=gaps.astype("<u4"), compress=True)
    create_dataset(g, "values", data=vals_s, compress=True)
    # Stored order → the given magnitude order: the rule reproduces it, or a rank is kept.
    rule = _rule_order_of_sorted(c.counts, vals_s)
    inverse = np.empty_like(by_loc)
    inverse[by_loc] = np.arange(by_loc.size)
    wanted = inverse  # position in sorted storage of the k-th coefficient in given order
    if not np.array_equal(rule, wanted):
        rank = np.empty(by_loc.size, dtype=np.int64)
        rank[wanted] = np.arange(by_loc.size) - np.repeat(c.offsets[:-1], c.counts)
        big = c.n_points and int(np.max(c.counts)) > 65535
        create_dataset(g, "rank", data=rank.astype("<u4" if big else "<u2"), compress=True)


def read_streams(
    g: h5py.Group, where: str, sizes: tuple[int, ...], counts: np.ndarray, total: int
) -> tuple[np.ndarray, np.ndarray]:
    """Read a schema-3 channel's streams; returns (values float32 (NNZ,), locations int32
    (NNZ, N)) in each point's magnitude order. Errors name the dataset."""
    for name in ("location_gaps", "values"):
        ds = checked_dataset(g, name, where, kinds="u" if name[0] == "l" else "f", shape=(None,))
        if ds.shape[0] != total:
            raise FileFormatError(
                f"{where}: counts sum to {total} coefficients but '{name}' holds {ds.shape[0]}"
            )
    raw_gaps = read_array(g, "location_gaps", where, kinds="u")
    limit = int(np.prod(sizes, dtype=np.int64))
    if raw_gaps.size and int(raw_gaps.max()) >= limit:  # before int64 sums could overflow
        i = int(np.argmax(raw_gaps >= limit))
        raise FileFormatError(
            f"{where}/location_gaps: entry {i} is {int(raw_gaps[i])}, beyond the {limit} "
            "entries of a data point"
        )
    gaps = raw_gaps.astype(np.int64)
    values = read_array(g, "values", where, kinds="f", finite=True)
    offsets = np.concatenate(([0], np.cumsum(counts, dtype=np.int64)))
    starts = offsets[:-1][counts > 0]
    first = np.zeros(total, dtype=bool)
    first[starts] = True
    if np.any((gaps == 0) & ~first):
        i = int(np.argmax((gaps == 0) & ~first))
        raise FileFormatError(
            f"{where}/location_gaps: entry {i} is 0 (a repeated location in its point); "
            "expected > 0 after a point's first entry"
        )
    run = np.cumsum(gaps)
    lin = run - np.repeat(run[starts] - gaps[starts], counts[counts > 0])
    if lin.size and int(lin.max()) >= limit:
        i = int(np.argmax(lin >= limit))
        raise FileFormatError(
            f"{where}/location_gaps: entry {i} reaches location {int(lin[i])}, outside the "
            f"{limit} entries of a data point"
        )
    if "rank" in g:
        rank = read_array(g, "rank", where, kinds="u", shape=(total,)).astype(np.int64)
        pos = offsets[:-1].repeat(counts) + rank
        if rank.size and (np.any(rank >= np.repeat(counts, counts)) or
                          np.unique(pos).size != pos.size):  # fmt: skip
            raise FileFormatError(
                f"{where}/rank: not a permutation of each point's coefficients"
            )
        order = np.empty(total, dtype=np.int64)
        order[pos] = np.arange(total)
    else:
        order = _rule_order_of_sorted(counts, values)
    return values[order].astype(np.float32), _unravel(lin[order], sizes)


def binary16_statistics(stats: Standardization) -> Standardization:
    """``stats`` with μ and σ rounded to binary16 (round to nearest even), so a coded file
    stores them in 2 bytes each, exactly (:func:`~sparsebtf.storage.model_file.exact_dtype`).

    The encoders standardise with the rounded values, so the codes are made for them: the
    rounding moves the standardisation, not the decoded values' fidelity. Rounding them
    *after* coding instead would change the decoded BTF by a linear-RGB MSE of about 4e-6
    of the codes' own error at SparseBTF(128) (``benchmarks/bench_storage.py``). Statistics
    that binary16 cannot hold well (σ below its smallest normal number 6.1e-5, or any value
    beyond ±65504) are returned unchanged (stored in float32).
    """
    tiny = float(np.finfo(np.float16).tiny)
    mean, std = np.asarray(stats.mean), np.asarray(stats.std)
    if std.size == 0 or float(std.min()) < tiny or max(float(np.abs(mean).max()),
                                                       float(std.max())) > _FP16_MAX:
        return stats
    return replace(stats, mean=mean.astype(np.float16).astype(np.float64),
                   std=std.astype(np.float16).astype(np.float64))  # fmt: skip

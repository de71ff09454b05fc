"""Schema-3 coefficient streams: each dictionary's locations once, which points use them, the
values as byte planes, with HDF5's built-in lossless filters (layout and inverse in
``docs/format.md`` §3).

Locations are column-major linear indices ``l = l1 + m1·l2 + m1·m2·l3 + …`` (MATLAB's
``sub2ind``, the release's index). The points coded on one dictionary share most of their
locations, so per channel::

    location_table (T,) <u4     per dictionary k = 0, 1, … (those with points): the distinct
                                locations its points use, increasing, as gaps (the first l,
                                each next l − previous l > 0)
    attr table_sizes (D,) <u4   entries of location_table per dictionary 0 … D−1
                                (D = largest membership + 1; 0 for a dictionary without points;
                                an attribute of the channel's group: a dataset costs ~400 bytes
                                of header)
    usage          (⌈Σ T_k·n_k / 8⌉,) u1   per dictionary a T_k × n_k bit matrix, bit (t, j)
                                set when the j-th point on k (by increasing point index) uses
                                entry t; the matrices row-major, one after the other, packed by
                                ``np.packbits`` (first bit the most significant)
    value_bytes    (B, NNZ) u1  the values in the order of the set bits, row b holding byte b of
                                each value's little-endian IEEE encoding: B = 2 (binary16), 4
                                (float32, when a value overflows binary16); rows are chunked
                                apart, so each is compressed on its own
    rank           (NNZ,) <u2|<u4   optional: in the same order, each coefficient's position
                                in its point's magnitude order, written only when that order is
                                not the rule below (codes from before the rule)

Table order puts a location used by several points once, with their values side by side;
byte planes give the values' sign-and-exponent byte and their mantissa byte deflate streams of
their own (deflate's one code table for both would cost ~1.3 bits per value). The values stay
exact. The reader restores each point's magnitude order — the order level of detail truncates
— by the **magnitude rule**: decreasing ``|stored value|``, ties by increasing ``l``.
:func:`canonical_codes` puts codes in that order (the encoders do, so their files need no
``rank``), hence a schema-3 file decodes to the very arrays, in the very order, of a schema-2
file of the same codes.

Files of schema 3's first layout (``location_gaps``: each point's sorted locations as gaps;
``values`` (NNZ,) in that order; ``rank`` in that order) are still read.
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


def _rule_order_of_sorted(counts: np.ndarray, values: np.ndarray,
                          pid: np.ndarray | None = None) -> np.ndarray:  # fmt: skip
    """:func:`magnitude_order` of coefficients whose point's entries come by increasing
    location (the stored orders; points may interleave: ``pid`` gives each one's point,
    default point after point): a stable sort on one integer key, point then decreasing
    magnitude (the IEEE bits of |v| order like |v|), keeps the location order of ties."""
    v = np.abs(np.asarray(values))
    pid = _point_ids(counts) if pid is None else pid
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
    # int32 division is several times faster than int64 (every UBO2014 index fits)
    dt = np.int32 if int(np.prod(sizes, dtype=np.int64)) < 2**31 else np.int64
    rest = lin.astype(dt)
    for n, m in enumerate(sizes):
        quot = rest // dt(m)
        out[:, n] = rest - quot * dt(m)
        rest = quot
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


def _gaps(lin: np.ndarray, starts: np.ndarray) -> np.ndarray:
    """Increasing runs of ``lin`` beginning at ``starts`` → gaps (a run's first entry kept)."""
    gaps = np.diff(lin, prepend=0)
    gaps[starts] = lin[starts]
    return gaps


def _bit_layout(membership: np.ndarray, table_sizes: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
    """Where each dictionary's usage matrix starts (bits, (D+1,)), its column count n_k (D,),
    and each point's column j (P,): its rank among the points on its dictionary."""
    n_k = np.bincount(membership, minlength=table_sizes.size)
    bit_start = np.concatenate(([0], np.cumsum(table_sizes * n_k)))
    by_dict = np.argsort(membership, kind="stable")
    col = np.empty(membership.size, dtype=np.int64)
    col[by_dict] = np.arange(membership.size) - np.repeat(np.cumsum(n_k) - n_k, n_k)
    return bit_start, n_k, col


def _location_tables(lin: np.ndarray, mem: np.ndarray, n_dicts: int
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
    """The distinct (dictionary, location) pairs of coefficients at ``lin`` on dictionaries
    ``mem``: (T,) the locations, dictionary after dictionary, each increasing; (D,) how many
    each dictionary has; (NNZ,) each coefficient's index into the first."""
    by = np.lexsort((lin, mem))
    new = np.ones(by.size, dtype=bool)
    new[1:] = (mem[by][1:] != mem[by][:-1]) | (lin[by][1:] != lin[by][:-1])
    entry = np.empty(by.size, dtype=np.int64)
    entry[by] = np.cumsum(new) - 1
    return lin[by][new], np.bincount(mem[by][new], minlength=n_dicts), entry


def write_streams(g: h5py.Group, c: SparseCodes, where: str) -> None:
    """Write ``location_table``, ``usage``, ``value_bytes`` (and ``rank`` if needed) of ``c``
    into ``g``, and its attribute ``table_sizes``."""
    sizes = tuple(int(m) for m in c.mode_sizes)
    vals = stored_values(c.values, where)
    lin = linear_locations(c.locations, sizes)
    pid = _point_ids(c.counts)
    membership = np.asarray(c.membership, dtype=np.int64)
    mem = membership[pid]
    table, table_sizes, entry = _location_tables(lin, mem, int(membership.max()) + 1
                                                 if c.n_points else 0)  # fmt: skip
    table_start = np.cumsum(table_sizes) - table_sizes
    bit_start, n_k, col = _bit_layout(membership, table_sizes)
    bit = bit_start[mem] + (entry - table_start[mem]) * n_k[mem] + col[pid]
    stored = np.argsort(bit)
    bit = bit[stored]
    if np.any(np.diff(bit) == 0):
        i = int(pid[stored][1:][np.argmax(np.diff(bit) == 0)])
        raise BTFInputError(f"{where}: point {i} repeats a location; locations must be unique")
    usage = np.bincount(bit >> 3, weights=np.right_shift(128, bit & 7),
                        minlength=-(-int(bit_start[-1]) // 8)).astype(np.uint8)  # fmt: skip
    little = vals[stored].astype(f"<f{vals.itemsize}")
    planes = np.ascontiguousarray(little.view(np.uint8).reshape(-1, vals.itemsize).T)
    create_dataset(g, "location_table", data=_gaps(table, table_start[table_sizes > 0])
                   .astype("<u4"), compress=True)  # fmt: skip
    g.attrs["table_sizes"] = table_sizes.astype("<u4")
    create_dataset(g, "usage", data=usage, compress=True)
    rows = {"chunks": (1, min(planes.shape[1], 1 << 20))} if planes.size else {}
    create_dataset(g, "value_bytes", data=planes, compress=True, **rows)  # planes apart
    # Stored order → the given magnitude order: the rule reproduces it, or a rank is kept.
    rule = _rule_order_of_sorted(np.asarray(c.counts), vals[stored], pid[stored])
    wanted = np.empty_like(stored)
    wanted[stored] = np.arange(stored.size)  # stored position of the k-th given coefficient
    if not np.array_equal(rule, wanted):
        rank = np.empty(stored.size, dtype=np.int64)
        rank[wanted] = np.arange(stored.size) - np.repeat(c.offsets[:-1], c.counts)
        big = c.n_points and int(np.max(c.counts)) > 65535
        create_dataset(g, "rank", data=rank.astype("<u4" if big else "<u2"), compress=True)


def _ungap(g: h5py.Group, name: str, where: str, runs: np.ndarray, limit: int) -> np.ndarray:
    """Dataset ``name`` of gaps, in increasing runs of lengths ``runs`` → (n,) int64 linear
    locations, each below ``limit``; a gap of 0 inside a run or a location beyond the limit
    is a :class:`FileFormatError` naming the entry."""
    raw = read_array(g, name, where, kinds="u", shape=(int(runs.sum()),))
    if raw.size and int(raw.max()) >= limit:  # before int64 sums could overflow
        i = int(np.argmax(raw >= limit))
        raise FileFormatError(
            f"{where}/{name}: entry {i} is {int(raw[i])}, beyond the {limit} entries of a "
            "data point"
        )
    gaps = raw.astype(np.int64)
    starts = (np.cumsum(runs) - runs)[runs > 0]
    first = np.zeros(gaps.size, dtype=bool)
    first[starts] = True
    if np.any((gaps == 0) & ~first):
        i = int(np.argmax((gaps == 0) & ~first))
        raise FileFormatError(
            f"{where}/{name}: entry {i} is 0 (a repeated location); expected > 0 after a "
            "run's first entry"
        )
    run = np.cumsum(gaps)
    lin = run - np.repeat(run[starts] - gaps[starts], runs[runs > 0])
    if lin.size and int(lin.max()) >= limit:
        i = int(np.argmax(lin >= limit))
        raise FileFormatError(
            f"{where}/{name}: entry {i} reaches location {int(lin[i])}, outside the "
            f"{limit} entries of a data point"
        )
    return lin




def _set_bits(
    bits: np.ndarray, bit_start: np.ndarray, membership: np.ndarray, table_sizes: np.ndarray,
    n_k: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """The set bits of the usage matrices, in stored order (row-major, matrix after matrix),
    as (point id, global table entry) pairs: (NNZ,) int64 each."""
    table_start, col_start = np.cumsum(table_sizes) - table_sizes, np.cumsum(n_k) - n_k
    points_by_dict = np.argsort(membership, kind="stable")
    entries, points = [np.zeros(0, np.int64)], [np.zeros(0, np.int64)]
    for k in np.flatnonzero(table_sizes * n_k):
        matrix = bits[bit_start[k] : bit_start[k + 1]].reshape(table_sizes[k], n_k[k])
        rows, cols = np.nonzero(matrix)
        entries.append(table_start[k] + rows)
        points.append(points_by_dict[col_start[k] + cols])
    return np.concatenate(points), np.concatenate(entries)


def _table_sizes(g: h5py.Group, where: str) -> np.ndarray:
    """The group's ``table_sizes`` attribute: (D,) non-negative integers → int64."""
    if "table_sizes" not in g.attrs:
        raise FileFormatError(f"{where}: missing attribute 'table_sizes'")
    raw = np.asarray(g.attrs["table_sizes"])
    if raw.ndim != 1 or raw.dtype.kind not in "iu" or (raw.size and int(raw.min()) < 0):
        raise FileFormatError(
            f"{where}: attribute 'table_sizes' must be a list of entry counts (>= 0), found "
            f"{raw.dtype} {raw.shape}"
        )
    return raw.astype(np.int64)


def _read_table(
    g: h5py.Group, where: str, sizes: tuple[int, ...], membership: np.ndarray,
    counts: np.ndarray, total: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
    """The table layout → (point id, linear location, value) of every coefficient, in stored
    order. Errors name the dataset."""
    n_points = membership.size
    held = checked_dataset(g, "value_bytes", where, kinds="u", shape=(None, None)).shape[1]
    if held != total:
        raise FileFormatError(
            f"{where}: counts sum to {total} coefficients but 'value_bytes' holds {held}"
        )
    table_sizes = _table_sizes(g, where)
    if n_points and table_sizes.size <= int(membership.max()):
        raise FileFormatError(
            f"{where}: attribute 'table_sizes' lists {table_sizes.size} dictionaries, but point "
            f"{int(np.argmax(membership >= table_sizes.size))} is coded on dictionary "
            f"{int(membership.max())}"
        )
    table_ds = checked_dataset(g, "location_table", where, kinds="u", shape=(None,))
    if table_ds.shape[0] != int(table_sizes.sum()):
        raise FileFormatError(
            f"{where}: attribute 'table_sizes' sums to {int(table_sizes.sum())} entries but "
            f"'location_table' holds {table_ds.shape[0]}"
        )
    table = _ungap(g, "location_table", where, table_sizes, int(np.prod(sizes, dtype=np.int64)))
    bit_start, n_k, _ = _bit_layout(membership.astype(np.int64), table_sizes)
    n_bytes = -(-int(bit_start[-1]) // 8)
    usage = read_array(g, "usage", where, kinds="u", shape=(n_bytes,))
    if usage.dtype.itemsize != 1:
        raise FileFormatError(f"{where}/usage: expected uint8 (packed bits), found {usage.dtype}")
    bits = np.unpackbits(usage).view(bool)
    if bits[bit_start[-1] :].any():
        raise FileFormatError(
            f"{where}/usage: bit {int(bit_start[-1]) + int(np.argmax(bits[bit_start[-1]:]))} "
            f"is set beyond the {int(bit_start[-1])} bits of the usage matrices"
        )
    pid, entry = _set_bits(bits, bit_start, membership, table_sizes, n_k)
    used = np.bincount(pid, minlength=n_points)
    if not np.array_equal(used, counts):
        i = int(np.argmax(used != counts))
        raise FileFormatError(
            f"{where}/usage: point {i} uses {int(used[i])} table entries but its count is "
            f"{int(counts[i])}"
        )
    planes = read_array(g, "value_bytes", where, kinds="u", shape=(None, total))
    if planes.dtype.itemsize != 1 or planes.shape[0] not in (2, 4):
        raise FileFormatError(
            f"{where}/value_bytes: expected (2, {total}) or (4, {total}) uint8, found "
            f"{planes.shape} {planes.dtype}"
        )
    values = np.ascontiguousarray(planes.T).view(f"<f{planes.shape[0]}")[:, 0]
    bad = ~np.isfinite(values)
    if bad.any():
        raise FileFormatError(
            f"{where}/value_bytes: {int(bad.sum())} NaN/Inf values (first at value "
            f"{int(np.argmax(bad))}); the file is damaged"
        )
    return pid, table[entry], values


def _read_gaps(
    g: h5py.Group, where: str, sizes: tuple[int, ...], counts: np.ndarray, total: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Schema 3's first layout (``location_gaps``, ``values``) → (point id, linear location,
    value) in stored order."""
    for name in ("location_gaps", "values"):
        ds = checked_dataset(g, name, where, kinds="u" if name[0] == "l" else "f", shape=(None,))
        if ds.shape[0] != total:
            raise FileFormatError(
                f"{where}: counts sum to {total} coefficients but '{name}' holds {ds.shape[0]}"
            )
    lin = _ungap(g, "location_gaps", where, counts, int(np.prod(sizes, dtype=np.int64)))
    values = read_array(g, "values", where, kinds="f", finite=True)
    return _point_ids(counts), lin, values


def read_streams(
    g: h5py.Group, where: str, sizes: tuple[int, ...], membership: np.ndarray,
    counts: np.ndarray, total: int,
) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """Read a schema-3 channel's streams (either layout); returns (values float32 (NNZ,),
    locations int32 (NNZ, N)) in each point's magnitude order. Errors name the dataset."""
    if "location_gaps" in g:
        pid, lin, values = _read_gaps(g, where, sizes, counts, total)
    else:
        pid, lin, values = _read_table(g, where, sizes, membership, counts, total)
    offsets = np.concatenate(([0], np.cumsum(counts, dtype=np.int64)))
    if "rank" in g:
        rank = read_array(g, "rank", where, kinds="u", shape=(total,)).astype(np.int64)
        pos = offsets[pid] + rank
        if rank.size and (np.any(rank >= counts[pid]) or np.unique(pos).size != pos.size):
            raise FileFormatError(
                f"{where}/rank: not a permutation of each point's coefficients"
            )
        order = np.empty(total, dtype=np.int64)
        order[pos] = np.arange(total)
    else:
        order = _rule_order_of_sorted(counts, values, pid)  # a point's locations increase
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

"""The highlight store in a coded file (:mod:`sparsebtf.learning.highlights`, issue 46).

A material with a store is written as **schema 5**: schema 3 plus one group ::

    /highlights             attrs: n_entries, space = "linear_rgb"
    /highlights/counts      (P,) uint32    entries of each point (release order)
    /highlights/keys        (N,) uint32    node keys, increasing within each point
    /highlights/rgb         (N, 3) float16 the linear-RGB corrections

compressed like schema 3's datasets. A store with per-texel highlight lobes
(:mod:`sparsebtf.learning.lobes`) is **schema 6**: schema 5 plus ::

    /highlights/lobes       (P, p², 8) float16 (ω_x, ω_y, ω_z, ln α_x, ln α_y, A_r, A_g, A_b)
                            per texel i1·p + i2 of each point

A **compact** store (every correction an E5M2 value, as the encoder makes them;
:mod:`sparsebtf.learning.entry_code`) is **schema 7**: the group holds, instead of counts, keys
and rgb ::

    /highlights             attrs: n_entries, space = "linear_rgb", rice_k (uint8),
                            has_lobes (0 or 1: whether /highlights/lobes is there)
    /highlights/unary       (U8,) uint8    the gaps' unary parts, MSB first, padded with 1s
    /highlights/remainder   (R8,) uint8    the gaps' low rice_k bits, MSB first
    /highlights/rgb8        (N, 3) uint8   the corrections as E5M2 bytes (binary16 = byte << 8)
    /highlights/lobes       as schema 6, where has_lobes is 1

the gaps between the sorted global keys ``point · p²·L·V + key`` (the points' entry counts
follow from them). A **tinted** compact store (one E5M2 scale an entry along a tint per
point, as the encoder makes them) is **schema 8**: schema 7 with, instead of rgb8 ::

    /highlights/scale8      (N,) uint8     each entry's scale as an E5M2 byte
    /highlights/tints       (P, 3) float16 each point's tint; a correction is
                            binary16(float32(scale) · float32(tint))

The schema number is raised each time so that a reader written before the store (or before
the lobes) refuses the file (one line: unsupported schema) instead of decoding it without
its corrections; a material without a store is still written as schema 3.
"""

from __future__ import annotations

import h5py
import numpy as np

from .._h5check import checked_dataset, read_array, read_int_attr, read_str_attr, require
from .._hdf5 import create_dataset, write_str_attr
from ..errors import BTFInputError, FileFormatError
from ..learning.entry_code import from_e5m2, pack_keys, to_e5m2, unpack_keys
from ..learning.highlights import Highlights, offsets_from_counts, tinted_corrections
from ..learning.lobes import LOBE_PARAMS

__all__ = ["COMPACT_SCHEMA", "HIGHLIGHT_SCHEMA", "HIGHLIGHT_SCHEMAS", "LOBE_SCHEMA",
           "TINT_SCHEMA", "read_highlights", "store_schema", "write_highlights"]  # fmt: skip

#: Schema of a coded file with a highlight store (schema 3's layout + ``/highlights``).
HIGHLIGHT_SCHEMA = 5
#: Schema of a coded file whose store has lobes (schema 5 + ``/highlights/lobes``).
LOBE_SCHEMA = 6
#: Schema of a coded file whose store is compact (its entries coded; lobes optional).
COMPACT_SCHEMA = 7
#: Schema of a coded file whose compact store is tinted (a scale an entry, a tint a point).
TINT_SCHEMA = 8
HIGHLIGHT_SCHEMAS = (HIGHLIGHT_SCHEMA, LOBE_SCHEMA, COMPACT_SCHEMA, TINT_SCHEMA)
_SPACE = "linear_rgb"
_MAX_RICE_K = 62


def store_schema(h: Highlights) -> int:
    """The schema a file with the store ``h`` is written in."""
    if h.tints is not None:
        return TINT_SCHEMA
    if h.compact:
        return COMPACT_SCHEMA
    return LOBE_SCHEMA if h.lobes is not None else HIGHLIGHT_SCHEMA


def write_highlights(f: h5py.File, h: Highlights, nodes_per_point: int) -> None:
    """The store as ``/highlights`` of the open coded file ``f`` (``nodes_per_point``:
    p²·L·V, the compact code's key stride)."""
    g = f.create_group("highlights")
    g.attrs["n_entries"] = h.n_entries
    write_str_attr(g, "space", _SPACE)
    if h.compact:
        k, unary, rem = pack_keys(h.global_keys(nodes_per_point))
        g.attrs["rice_k"] = np.uint8(k)
        g.attrs["has_lobes"] = np.uint8(h.lobes is not None)
        create_dataset(g, "unary", data=unary, compress=True)
        create_dataset(g, "remainder", data=rem, compress=True)
        if h.tints is not None:
            create_dataset(g, "scale8", data=to_e5m2(h.scales), compress=True)
            create_dataset(g, "tints", data=np.asarray(h.tints, dtype="<f2"), compress=True)
        else:
            create_dataset(g, "rgb8", data=to_e5m2(h.rgb), compress=True)
    else:
        create_dataset(g, "counts", data=np.diff(h.offsets).astype("<u4"), compress=True)
        create_dataset(g, "keys", data=np.asarray(h.keys, dtype="<u4"), compress=True)
        create_dataset(g, "rgb", data=np.asarray(h.rgb, dtype="<f2"), compress=True)
    if h.lobes is not None:
        create_dataset(g, "lobes", data=np.asarray(h.lobes, dtype="<f2"), compress=True)


def read_highlights(f: h5py.File, where: str, n_points: int, patch: int, n_lights: int,
                    n_views: int, schema: int = HIGHLIGHT_SCHEMA) -> Highlights:  # fmt: skip
    """``/highlights`` of a schema-5 to 8 file, every field checked (sizes before reading,
    keys inside the point's nodes and increasing, values finite, lobes in schema 6 to 8
    only)."""
    at = f"{where}/highlights"
    g = require(f, "highlights", where)
    if not isinstance(g, h5py.Group):
        raise FileFormatError(f"{at}: expected a group, found a dataset")
    space = read_str_attr(g, "space", at)
    if space != _SPACE:
        raise FileFormatError(f"{at}: space {space!r}, expected {_SPACE!r}")
    limit = n_points * patch * patch * n_lights * n_views
    n = read_int_attr(g, "n_entries", at, 0, limit)
    tints = scales = None
    if schema in (COMPACT_SCHEMA, TINT_SCHEMA):
        offsets, keys = _read_compact(g, at, n, n_points, patch * patch * n_lights * n_views)
        if schema == TINT_SCHEMA:
            scales = _read_e5m2(g, "scale8", at, (n,))
            tints = read_array(g, "tints", at, "f", (n_points, 3)).astype(np.float16)
            # before the corrections are derived from them (Highlights.check comes after)
            if not np.all(np.isfinite(tints)):
                i = int(np.flatnonzero(~np.isfinite(tints).all(axis=1))[0])
                raise FileFormatError(f"{at}/tints: the tint of point {i} is not finite")
            rgb = tinted_corrections(offsets, scales, tints)
        else:
            rgb = _read_e5m2(g, "rgb8", at, (n, 3))
    else:
        counts = read_array(g, "counts", at, "u", (n_points,)).astype(np.int64)
        if int(counts.sum()) != n:
            raise FileFormatError(f"{at}/counts: sums to {int(counts.sum())}, n_entries is {n}")
        keys = read_array(g, "keys", at, "u", (n,))
        rgb = read_array(g, "rgb", at, "f", (n, 3))
        offsets = offsets_from_counts(counts)
    lobes = None
    # a schema-7/8 store says whether it has lobes, so that losing them is damage, not a choice
    has_lobes = (schema == LOBE_SCHEMA
                 or (schema in (COMPACT_SCHEMA, TINT_SCHEMA)
                     and read_int_attr(g, "has_lobes", at, 0, 1) == 1))
    if has_lobes:
        lobes = read_array(g, "lobes", at, "f", (n_points, patch * patch, LOBE_PARAMS))
        lobes = lobes.astype(np.float16)
    elif "lobes" in g:
        raise FileFormatError(f"{at}/lobes: lobes in a schema-{schema} file without them "
                              f"(schema {LOBE_SCHEMA} holds them, {COMPACT_SCHEMA} and "
                              f"{TINT_SCHEMA} with has_lobes = 1)")  # fmt: skip
    h = Highlights(offsets, keys.astype(np.uint32), rgb.astype(np.float16), lobes, tints, scales)
    try:
        h.check(n_points, patch, n_lights, n_views, at)
    except BTFInputError as e:
        raise FileFormatError(str(e)) from None
    return h


def _read_compact(g: h5py.Group, at: str, n: int, n_points: int,
                  nodes: int) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """Offsets and keys of a schema-7/8 store (``nodes`` a point), checked: the streams'
    lengths before reading (the unary stream holds at least one bit an entry and at most
    ⌈(n + (P·nodes >> k))/8⌉ bytes: n ends, and unary parts of gaps summing below the
    P·nodes nodes), the keys inside the material."""
    k = read_int_attr(g, "rice_k", at, 0, _MAX_RICE_K)
    limit = n_points * nodes
    most = -(-(n + (limit >> k)) // 8)  # n entries, and gaps summing below the nodes
    ds = checked_dataset(g, "unary", at, "u", (None,))
    if not n <= 8 * ds.shape[0] or ds.shape[0] > most:
        raise FileFormatError(f"{at}/unary: {ds.shape[0]} bytes cannot hold {n} entries "
                              f"among {limit} nodes (at most {most})")  # fmt: skip
    unary = read_array(g, "unary", at, "u", (None,))
    remainder = read_array(g, "remainder", at, "u", (-(-n * k // 8),))
    for name, a in (("unary", unary), ("remainder", remainder)):
        if a.dtype.itemsize != 1:
            raise FileFormatError(f"{at}/{name}: expected uint8, found {a.dtype}")
    try:
        glob = unpack_keys(k, unary.astype(np.uint8), remainder.astype(np.uint8), n)
    except ValueError as e:
        raise FileFormatError(f"{at}/unary: {e}") from None
    if n and int(glob[-1]) >= limit:
        raise FileFormatError(f"{at}/unary: key {int(glob[-1])} of entry {n - 1} is past the "
                              f"{limit} nodes of {n_points} points")  # fmt: skip
    pts, keys = np.divmod(glob, nodes)
    offsets = offsets_from_counts(np.bincount(pts, minlength=n_points))
    return offsets, keys.astype(np.uint32)


def _read_e5m2(g: h5py.Group, name: str, at: str, shape: tuple[int, ...]) -> np.ndarray:
    """The E5M2 bytes ``name`` of ``shape``, checked (uint8, finite) as binary16."""
    a = read_array(g, name, at, "u", shape)
    if a.dtype.itemsize != 1:
        raise FileFormatError(f"{at}/{name}: expected uint8, found {a.dtype}")
    bad = (a.astype(np.uint8) & 0x7C) == 0x7C
    if bad.any():
        i = int(np.flatnonzero(bad.reshape(len(a), -1).any(axis=1))[0])
        raise FileFormatError(f"{at}/{name}: entry {i} is not finite (E5M2 exponent 31)")
    return from_e5m2(a.astype(np.uint8))

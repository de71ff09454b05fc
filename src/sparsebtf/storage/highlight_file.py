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

The schema number is raised each time so that a reader written before the store (or before
the lobes) refuses the file (one line: unsupported schema) instead of decoding it without
its corrections; a material without a store is still written as schema 3.
"""

from __future__ import annotations

import h5py
import numpy as np

from .._h5check import read_array, read_int_attr, read_str_attr, require
from .._hdf5 import create_dataset, write_str_attr
from ..errors import BTFInputError, FileFormatError
from ..learning.highlights import Highlights
from ..learning.lobes import LOBE_PARAMS

__all__ = ["HIGHLIGHT_SCHEMA", "HIGHLIGHT_SCHEMAS", "LOBE_SCHEMA", "read_highlights",
           "store_schema", "write_highlights"]  # fmt: skip

#: Schema of a coded file with a highlight store (schema 3's layout + ``/highlights``).
HIGHLIGHT_SCHEMA = 5
#: Schema of a coded file whose store has lobes (schema 5 + ``/highlights/lobes``).
LOBE_SCHEMA = 6
HIGHLIGHT_SCHEMAS = (HIGHLIGHT_SCHEMA, LOBE_SCHEMA)
_SPACE = "linear_rgb"


def store_schema(h: Highlights) -> int:
    """The schema a file with the store ``h`` is written in."""
    return LOBE_SCHEMA if h.lobes is not None else HIGHLIGHT_SCHEMA


def write_highlights(f: h5py.File, h: Highlights) -> None:
    """The store as ``/highlights`` of the open coded file ``f``."""
    g = f.create_group("highlights")
    g.attrs["n_entries"] = h.n_entries
    write_str_attr(g, "space", _SPACE)
    create_dataset(g, "counts", data=np.diff(h.offsets).astype("<u4"), compress=True)
    create_dataset(g, "keys", data=np.asarray(h.keys, dtype="<u4"), compress=True)
    create_dataset(g, "rgb", data=np.asarray(h.rgb, dtype="<f2"), compress=True)
    if h.lobes is not None:
        create_dataset(g, "lobes", data=np.asarray(h.lobes, dtype="<f2"), compress=True)


def read_highlights(f: h5py.File, where: str, n_points: int, patch: int, n_lights: int,
                    n_views: int, schema: int = HIGHLIGHT_SCHEMA) -> Highlights:  # fmt: skip
    """``/highlights`` of a schema-5 or 6 file, every field checked (sizes before reading,
    keys inside the point's nodes and increasing, values finite, lobes in schema 6 only)."""
    at = f"{where}/highlights"
    g = require(f, "highlights", where)
    if not isinstance(g, h5py.Group):
        raise FileFormatError(f"{at}: expected a group, found a dataset")
    space = read_str_attr(g, "space", at)
    if space != _SPACE:
        raise FileFormatError(f"{at}: space {space!r}, expected {_SPACE!r}")
    limit = n_points * patch * patch * n_lights * n_views
    n = read_int_attr(g, "n_entries", at, 0, limit)
    counts = read_array(g, "counts", at, "u", (n_points,)).astype(np.int64)
    if int(counts.sum()) != n:
        raise FileFormatError(f"{at}/counts: sums to {int(counts.sum())}, n_entries is {n}")
    keys = read_array(g, "keys", at, "u", (n,))
    rgb = read_array(g, "rgb", at, "f", (n, 3))
    offsets = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    lobes = None
    if schema == LOBE_SCHEMA:
        lobes = read_array(g, "lobes", at, "f", (n_points, patch * patch, LOBE_PARAMS))
        lobes = lobes.astype(np.float16)
    elif "lobes" in g:
        raise FileFormatError(f"{at}/lobes: lobes in a schema-{schema} file (schema "
                              f"{LOBE_SCHEMA} holds them)")  # fmt: skip
    h = Highlights(offsets, keys.astype(np.uint32), rgb.astype(np.float16), lobes)
    try:
        h.check(n_points, patch, n_lights, n_views, at)
    except BTFInputError as e:
        raise FileFormatError(str(e)) from None
    return h

"""The highlight store in a coded file (:mod:`sparsebtf.learning.highlights`, issue 46).

A material with a store is written as **schema 5**: schema 3 plus one group ::

    /highlights             attrs: n_entries, space = "linear_rgb"
    /highlights/counts      (P,) uint32    entries of each point (release order)
    /highlights/keys        (N,) uint32    node keys, increasing within each point
    /highlights/rgb         (N, 3) float16 the linear-RGB corrections

compressed like schema 3's datasets. The schema number is raised so that a reader written
before the store refuses the file (one line: unsupported schema) instead of decoding it
without its corrections; a material without a store is still written as schema 3.
"""

from __future__ import annotations

import h5py
import numpy as np

from .._h5check import read_array, read_int_attr, read_str_attr, require
from .._hdf5 import create_dataset, write_str_attr
from ..errors import BTFInputError, FileFormatError
from ..learning.highlights import Highlights

__all__ = ["HIGHLIGHT_SCHEMA", "read_highlights", "write_highlights"]

#: Schema of a coded file with a highlight store (schema 3's layout + ``/highlights``).
HIGHLIGHT_SCHEMA = 5
_SPACE = "linear_rgb"


def write_highlights(f: h5py.File, h: Highlights) -> None:
    """The store as ``/highlights`` of the open coded file ``f``."""
    g = f.create_group("highlights")
    g.attrs["n_entries"] = h.n_entries
    write_str_attr(g, "space", _SPACE)
    create_dataset(g, "counts", data=np.diff(h.offsets).astype("<u4"), compress=True)
    create_dataset(g, "keys", data=np.asarray(h.keys, dtype="<u4"), compress=True)
    create_dataset(g, "rgb", data=np.asarray(h.rgb, dtype="<f2"), compress=True)


def read_highlights(f: h5py.File, where: str, n_points: int, patch: int, n_lights: int,
                    n_views: int) -> Highlights:  # fmt: skip
    """``/highlights`` of a schema-5 file, every field checked (sizes before reading, keys
    inside the point's nodes and increasing, values finite)."""
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
    h = Highlights(offsets, keys.astype(np.uint32), rgb.astype(np.float16))
    try:
        h.check(n_points, patch, n_lights, n_views, at)
    except BTFInputError as e:
        raise FileFormatError(str(e)) from None
    return h

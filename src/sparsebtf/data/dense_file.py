"""Our dense BTF file: one chunked HDF5 dataset, readable from h5py or MATLAB without this code.

Layout (schema ``sparsebtf-dense`` version 2, documented in ``docs/format.md``)::

    /                      attrs: format="sparsebtf-dense", schema_version=2, name, attrs_json
    /btf                   (H, W, L, V, 3) float32 or float16, linear RGB, chunked
    /lights/xyz            (L, 3) float64 unit vectors, tangent frame (z = normal)
    /lights/theta, /phi    (L,) float64 radians (polar from the normal, azimuth)
    /views/xyz, ...        the same for the view directions

The chunk is (20, 20, 8, 8, 3) by default (clipped to the shape): a 20×20 spatial tile with
all directions is read without waste (two 10×10 data points per side), and one angular image
reads 64× its size, not the whole file. Writes stream view blocks, atomically. Schema 2 adds
the fletcher32 checksum to every dataset and HDF5 1.10 structures with metadata checksums
(:mod:`sparsebtf._hdf5`); schema 1 files (no checksums) still load.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from .._atomic import atomic_output
from .._h5check import (
    HDF5_ERRORS,
    checked_dataset,
    read_array,
    read_int_attr,
    read_json_attr,
    read_str_attr,
    require,
)
from .._hdf5 import check_written, create, create_dataset, open_h5, read_error, write_str_attr
from .._limits import memory_budget
from .._progress import progress as _progress
from .._semantic import check_directions
from ..errors import BTFInputError, FileFormatError, SparseBTFError
from .btf import BTF, Index
from .chunks import ChunkReader
from .directions import DirectionSet, from_vectors, unit_vectors

__all__ = [
    "DEFAULT_CHUNK", "FORMAT", "SCHEMA_VERSION", "DenseFileBTF", "chunk_cache_bytes",
    "dense_file_bytes", "write_dense", "write_header",
]  # fmt: skip

FORMAT = "sparsebtf-dense"
SCHEMA_VERSION = 2
_SUPPORTED = (1, 2)
DEFAULT_CHUNK = (20, 20, 8, 8, 3)


def write_directions(group: h5py.Group, d: DirectionSet) -> None:
    """Write a direction table (name attr, xyz, theta, phi) into ``group``."""
    write_str_attr(group, "name", d.name)
    create_dataset(group, "xyz", data=d.xyz)
    create_dataset(group, "theta", data=d.theta)
    create_dataset(group, "phi", data=d.phi)


def read_directions(group: h5py.Group, where: str) -> DirectionSet:
    """Read a direction table written by :func:`write_directions`; errors name the file field.

    ``xyz`` is checked (float, (n, 3), a size the file holds) before it is read, and after:
    finite unit vectors on the upper hemisphere, pairwise distinct
    (:func:`sparsebtf._semantic.check_directions`); never normalised silently.
    """
    if not isinstance(group, h5py.Group):
        raise FileFormatError(f"{where}: expected a group, found a dataset")
    xyz = read_array(group, "xyz", where, kinds="f", shape=(None, 3), finite=True)
    if xyz.shape[0] == 0:
        raise FileFormatError(f"{where}/xyz: expected at least one direction, found 0")
    check_directions(xyz, f"{where}/xyz")
    for key in ("theta", "phi"):  # redundant with xyz, but a damaged copy is damage
        if key in group:
            check_angles(group, key, xyz, where)
    name = read_str_attr(group, "name", where) if "name" in group.attrs else "custom"
    try:
        return from_vectors(xyz.astype(np.float64), name=name)
    except BTFInputError as e:
        raise FileFormatError(f"{where}/xyz: {e}") from None


#: Largest distance between ``xyz`` and the unit vector of its stored (θ, φ): float32 angles
#: are within 1e-6 of it; a damaged angle is off by far more.
ANGLE_TOLERANCE = 1e-5


def check_angles(group: h5py.Group, key: str, xyz: np.ndarray, where: str) -> None:
    """The table's ``theta`` or ``phi`` dataset: (n,) finite radians giving back ``xyz``.

    Readers take directions from ``xyz`` alone; the angles are kept for other tools, so a
    copy that disagrees with ``xyz`` is refused rather than left to mislead them.
    """
    n = len(xyz)
    angles = read_array(group, key, where, kinds="f", shape=(n,), finite=True)
    exact = from_vectors(xyz.astype(np.float64))
    theta = angles if key == "theta" else exact.theta
    phi = angles if key == "phi" else exact.phi
    off = np.abs(unit_vectors(theta.astype(np.float64), phi.astype(np.float64)) - exact.xyz)
    # (at the pole any azimuth gives the same vector: there only θ is checked, by nature)
    worst = int(np.argmax(off.max(axis=1)))
    if float(off[worst].max()) > ANGLE_TOLERANCE:
        raise FileFormatError(
            f"{where}/{key}: direction {worst} has {key} {float(angles[worst]):.6g}, but xyz "
            f"gives {float(getattr(exact, key)[worst]):.6g} (radians); the angle table "
            "disagrees with xyz: the file is damaged"
        )


def _chunk(shape: Sequence[int], chunks: Sequence[int] | None) -> tuple[int, ...]:
    return tuple(min(c, s) for c, s in zip(chunks or DEFAULT_CHUNK, shape, strict=True))


def dense_file_bytes(
    shape: Sequence[int], dtype: str = "float32", chunks: Sequence[int] | None = None
) -> int:
    """Bytes the values of :func:`write_dense`'s file take on disk: every chunk is stored
    whole (edge chunks padded), uncompressed; the header and direction tables add a few KiB."""
    chunk = _chunk(shape, chunks)
    n_chunks = math.prod(-(-s // c) for s, c in zip(shape, chunk, strict=True))
    return n_chunks * math.prod(chunk) * np.dtype(dtype).itemsize


def write_header(
    f: h5py.File,
    shape: Sequence[int],
    dtype: str,
    name: str,
    attrs: dict[str, Any],
    lights: DirectionSet,
    views: DirectionSet,
    chunks: Sequence[int] | None = None,
) -> h5py.Dataset:
    """Everything of a dense file but its values, into the new file ``f``: the root
    attributes (format, schema_version, name, attrs_json), the empty ``/btf`` dataset of
    ``shape`` (H, W, L, V, 3) and ``dtype``, chunked (:data:`DEFAULT_CHUNK` clipped to the
    shape unless ``chunks``), and the direction tables. Returns ``/btf`` for the writer to
    fill. The one header writer of dense files (:func:`write_dense`, the capture's)."""
    write_str_attr(f, "format", FORMAT)
    f.attrs["schema_version"] = SCHEMA_VERSION
    write_str_attr(f, "name", name)
    write_str_attr(f, "attrs_json", json.dumps(attrs, sort_keys=True, default=str))
    ds = create_dataset(f, "btf", shape=tuple(shape), dtype=dtype, chunks=_chunk(shape, chunks))
    write_directions(f.create_group("lights"), lights)
    write_directions(f.create_group("views"), views)
    return ds


def write_dense(
    path: str | os.PathLike[str],
    btf: BTF,
    *,
    dtype: str = "float32",
    chunks: tuple[int, int, int, int, int] | None = None,
    attrs: dict[str, Any] | None = None,
    progress: bool | None = False,
    by: str = "views",
) -> Path:
    """Write ``btf`` to ``path`` in our dense format, streaming.

    ``by="views"`` streams groups of view blocks (memory H·W·L·8·3 values; the natural order
    of measured and synthetic sources); ``by="regions"`` streams spatial tiles of the chunk
    size with all directions (memory 20·20·L·V·3 values; the natural order of decoded BTFs,
    whose data points each hold every direction). Values must be finite; a NaN or Inf aborts
    with its count and first location, leaving no file.
    """
    if by not in ("views", "regions"):
        raise BTFInputError(f"write_dense streams by 'views' or 'regions', not {by!r}")
    if dtype not in ("float32", "float16"):
        raise BTFInputError(f"dense files store float32 or float16, not {dtype!r}")
    shape = btf.shape
    chunk = _chunk(shape, chunks)
    meta = dict(btf.attrs)
    meta.update(attrs or {})
    target = Path(path)
    nv = shape[3]
    step = chunk[3]
    with atomic_output(target) as tmp:
        with create(tmp) as f:
            ds = write_header(f, shape, dtype, btf.name, meta, btf.lights, btf.views, chunk)
            if by == "views":
                blocks = [
                    (slice(None), slice(None), slice(v0, min(v0 + step, nv)))
                    for v0 in range(0, nv, step)
                ]
            else:
                blocks = [
                    (slice(r0, min(r0 + chunk[0], shape[0])),
                     slice(c0, min(c0 + chunk[1], shape[1])), slice(None))
                    for c0 in range(0, shape[1], chunk[1])
                    for r0 in range(0, shape[0], chunk[0])
                ]
            for rows, cols, views in _progress(blocks, total=len(blocks), desc="write",
                                               enabled=progress):
                block = btf.read(rows, cols, slice(None), views)
                bad = ~np.isfinite(block)
                if bad.any():
                    r, c, li, vj, ch = (int(x[0]) for x in np.nonzero(bad))
                    r += rows.start or 0
                    c += cols.start or 0
                    vj += views.start or 0
                    raise BTFInputError(
                        f"{btf.label}: {int(bad.sum())} NaN/Inf values; first at row {r}, "
                        f"col {c}, light {li}, view {vj}, channel {ch}"
                    )
                ds[rows, cols, :, views, :] = block
                check_written(f)  # a full disk stops the write here
    return target


#: The smallest chunk cache (HDF5's default).
_MIN_CACHE = 2**20


def _with_chunk_cache(ds: h5py.Dataset, nbytes: int) -> h5py.Dataset:
    """``ds`` closed and opened again with a chunk cache of its own of ``nbytes`` (HDF5
    shares one cache between the openings of a dataset: the first must be closed)."""
    fid, name = ds.file.id, ds.name.encode()
    ds.id.close()
    dapl = h5py.h5p.create(h5py.h5p.DATASET_ACCESS)
    dapl.set_chunk_cache(max(10007, nbytes // 2**14 | 1), nbytes, 0.75)
    return h5py.Dataset(h5py.h5d.open(fid, name, dapl))


def chunk_cache_bytes(
    shape: Sequence[int], chunks: Sequence[int] | None, dtype: np.dtype
) -> int:
    """The HDF5 chunk cache of an open dense file: the chunks of one chunk-sized spatial tile
    with every direction (checksummed chunks are read and verified whole, so the data points
    of a tile read each chunk once), at most an eighth of the memory budget.

    111 MiB for float32 at 151 × 151 directions in the default 20 × 20 × 8 × 8 × 3 chunks,
    where the eighth of the budget (256 MiB, the earlier size) made ``sparsebtf demo``, with
    its 7 materials open, hold 1.8 GB of caches.
    """
    if chunks is None:
        return _MIN_CACHE
    chunk = math.prod(chunks) * np.dtype(dtype).itemsize
    per_tile = math.prod(-(-s // c) for s, c in zip(shape[2:], chunks[2:], strict=True))
    return int(max(_MIN_CACHE, min(memory_budget() // 8, chunk * per_tile)))


class DenseFileBTF(BTF):
    """A BTF stored in our dense HDF5 file; reads only the chunks a request touches."""

    serial_reads = True

    #: HDF5 chunk cache per open file in bytes (None: :func:`chunk_cache_bytes`).
    chunk_cache: int | None = None

    def __init__(self, path: str | os.PathLike[str]) -> None:
        self.path = Path(path)
        f = open_h5(self.path)
        try:
            ds, lights, views, name, attrs = _open_dense(f, str(self.path))
            cache = self.chunk_cache or chunk_cache_bytes(ds.shape, ds.chunks, ds.dtype)
            ds = _with_chunk_cache(ds, cache)
            # the chunks read and verified here, h5py's filter pipeline left for the rest
            self._chunks = ChunkReader.of(ds, cache)
        except SparseBTFError:
            f.close()
            raise
        except HDF5_ERRORS as e:
            f.close()
            raise read_error(e, str(self.path)) from None
        super().__init__(ds.shape[0], ds.shape[1], lights, views, name, attrs)
        self._file = f
        self._ds = ds
        if ds.chunks is not None:  # scans read whole chunks: their rows and views at once
            self.block_hint = (int(ds.chunks[0]), int(ds.chunks[3]))

    def __reduce__(self) -> tuple[Any, tuple[str]]:
        # Pickled as its path (Dask workers reopen it; an open HDF5 file cannot travel).
        return DenseFileBTF, (str(self.path.absolute()),)

    @property
    def dtype(self) -> np.dtype:
        return self._ds.dtype

    def close(self) -> None:
        self._file.close()

    def __enter__(self) -> DenseFileBTF:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def read(self, rows: Index, cols: Index, lights: Index, views: Index) -> np.ndarray:
        idx = list(self.indices(rows, cols, lights, views))
        if any(ix.size == 0 for ix in idx):
            return np.empty((*(ix.size for ix in idx), 3), dtype=np.float32)
        # HDF5 reads hyperslabs: read the bounding box, then pick the requested entries.
        box = tuple(slice(int(ix.min()), int(ix.max()) + 1) for ix in idx)
        try:
            data = None if self._chunks is None else self._chunks.read((*box, slice(0, 3)))
            if data is None:
                data = np.asarray(self._ds[box], dtype=np.float32)
        except HDF5_ERRORS as e:
            raise read_error(e, f"{self.path}/btf") from None
        rel = [ix - ix.min() for ix in idx]
        if all(
            r.size == (b.stop - b.start) and np.all(np.diff(r) == 1)
            for r, b in zip(rel, box, strict=True)
        ):
            return data
        return data[np.ix_(*rel, np.arange(3))]


def _open_dense(
    f: h5py.File, where: str
) -> tuple[h5py.Dataset, DirectionSet, DirectionSet, str, dict[str, Any]]:
    """Check a dense file's attributes, ``/btf`` (without reading it) and direction tables."""
    fmt = read_str_attr(f, "format", where) if "format" in f.attrs else None
    if fmt != FORMAT:
        raise FileFormatError(f"{where}: attribute 'format' is {fmt!r}, not {FORMAT!r}")
    version = read_int_attr(f, "schema_version", where)
    if version not in _SUPPORTED:
        raise FileFormatError(
            f"{where}: schema_version {version} is not supported (this reader: "
            f"{', '.join(map(str, _SUPPORTED))})"
        )
    ds = checked_dataset(f, "btf", where, kinds="f", shape=(None, None, None, None, 3), whole=False)
    if min(ds.shape) < 1:
        raise FileFormatError(
            f"{where}/btf: expected a non-empty (H, W, L, V, 3), found {ds.shape}"
        )
    lights = read_directions(require(f, "lights", where), f"{where}/lights")
    views = read_directions(require(f, "views", where), f"{where}/views")
    if (len(lights), len(views)) != ds.shape[2:4]:
        raise FileFormatError(
            f"{where}: /btf has {ds.shape[2]} lights x {ds.shape[3]} views but the "
            f"direction tables have {len(lights)} x {len(views)}"
        )
    name = read_str_attr(f, "name", where) if "name" in f.attrs else Path(where).stem
    attrs = read_json_attr(f, "attrs_json", where)
    return ds, lights, views, name, attrs

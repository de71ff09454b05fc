"""Our dense BTF file: one chunked HDF5 dataset, readable from h5py or MATLAB without this code.

Layout (schema ``sparsebtf-dense`` version 1, documented in ``docs/format.md``)::

    /                      attrs: format="sparsebtf-dense", schema_version=1, name, attrs_json
    /btf                   (H, W, L, V, 3) float32 or float16, linear RGB, chunked
    /lights/xyz            (L, 3) float64 unit vectors, tangent frame (z = normal)
    /lights/theta, /phi    (L,) float64 radians (polar from the normal, azimuth)
    /views/xyz, ...        the same for the view directions

The chunk is (20, 20, 8, 8, 3) by default (clipped to the shape): a 20×20 spatial tile with
all directions is read without waste (two 10×10 data points per side), and one angular image
reads 64× its size, not the whole file. Writes stream view blocks, atomically.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from .._atomic import atomic_output
from .._progress import progress as _progress
from ..errors import BTFInputError, FileFormatError
from .btf import BTF, Index
from .directions import DirectionSet, from_vectors

__all__ = ["DEFAULT_CHUNK", "FORMAT", "SCHEMA_VERSION", "DenseFileBTF", "write_dense"]

FORMAT = "sparsebtf-dense"
SCHEMA_VERSION = 1
DEFAULT_CHUNK = (20, 20, 8, 8, 3)


def write_directions(group: h5py.Group, d: DirectionSet) -> None:
    """Write a direction table (name attr, xyz, theta, phi) into ``group``."""
    group.attrs["name"] = d.name
    group.create_dataset("xyz", data=d.xyz)
    group.create_dataset("theta", data=d.theta)
    group.create_dataset("phi", data=d.phi)


def read_directions(group: h5py.Group, where: str) -> DirectionSet:
    """Read a direction table written by :func:`write_directions`; errors name the file field."""
    if "xyz" not in group:
        raise FileFormatError(f"{where}: missing dataset 'xyz'")
    xyz = np.asarray(group["xyz"], dtype=np.float64)
    if xyz.ndim != 2 or xyz.shape[1] != 3:
        raise FileFormatError(f"{where}/xyz: expected shape (n, 3), got {xyz.shape}")
    name = group.attrs.get("name", "custom")
    name = name.decode() if isinstance(name, bytes) else str(name)
    try:
        return from_vectors(xyz, name=name)
    except BTFInputError as e:
        raise FileFormatError(f"{where}/xyz: {e}") from None


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
    chunk = tuple(min(c, s) for c, s in zip(chunks or DEFAULT_CHUNK, shape, strict=True))
    meta = dict(btf.attrs)
    meta.update(attrs or {})
    target = Path(path)
    nv = shape[3]
    step = chunk[3]
    with atomic_output(target) as tmp:
        with h5py.File(tmp, "w") as f:
            f.attrs["format"] = FORMAT
            f.attrs["schema_version"] = SCHEMA_VERSION
            f.attrs["name"] = btf.name
            f.attrs["attrs_json"] = json.dumps(meta, sort_keys=True, default=str)
            ds = f.create_dataset("btf", shape=shape, dtype=dtype, chunks=chunk)
            write_directions(f.create_group("lights"), btf.lights)
            write_directions(f.create_group("views"), btf.views)
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
                        f"{btf.name}: {int(bad.sum())} NaN/Inf values; first at row {r}, "
                        f"col {c}, light {li}, view {vj}, channel {ch}"
                    )
                ds[rows, cols, :, views, :] = block
    return target


class DenseFileBTF(BTF):
    """A BTF stored in our dense HDF5 file; reads only the chunks a request touches."""

    def __init__(self, path: str | os.PathLike[str]) -> None:
        self.path = Path(path)
        if not self.path.exists():
            raise FileFormatError(f"{self.path}: no such file")
        try:
            f = h5py.File(self.path, "r")
        except OSError as e:
            raise FileFormatError(f"{self.path}: not a readable HDF5 file ({e})") from None
        fmt = f.attrs.get("format")
        fmt = fmt.decode() if isinstance(fmt, bytes) else fmt
        if fmt != FORMAT:
            f.close()
            raise FileFormatError(f"{self.path}: attribute 'format' is {fmt!r}, not {FORMAT!r}")
        version = int(f.attrs.get("schema_version", -1))
        if version != SCHEMA_VERSION:
            f.close()
            raise FileFormatError(
                f"{self.path}: schema_version {version} is not supported (this reader: "
                f"{SCHEMA_VERSION})"
            )
        if "btf" not in f:
            f.close()
            raise FileFormatError(f"{self.path}: missing dataset 'btf'")
        ds = f["btf"]
        if ds.ndim != 5 or ds.shape[4] != 3:
            f.close()
            raise FileFormatError(
                f"{self.path}/btf: expected shape (H, W, L, V, 3), got {ds.shape}"
            )
        lights = read_directions(f["lights"], f"{self.path}/lights")
        views = read_directions(f["views"], f"{self.path}/views")
        if (len(lights), len(views)) != ds.shape[2:4]:
            f.close()
            raise FileFormatError(
                f"{self.path}: /btf has {ds.shape[2]} lights x {ds.shape[3]} views but the "
                f"direction tables have {len(lights)} x {len(views)}"
            )
        name = f.attrs.get("name", self.path.stem)
        name = name.decode() if isinstance(name, bytes) else str(name)
        attrs = json.loads(f.attrs.get("attrs_json", "{}"))
        super().__init__(ds.shape[0], ds.shape[1], lights, views, name, attrs)
        self._file = f
        self._ds = ds

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
        data = np.asarray(self._ds[box], dtype=np.float32)
        rel = [ix - ix.min() for ix in idx]
        if all(
            r.size == (b.stop - b.start) and np.all(np.diff(r) == 1)
            for r, b in zip(rel, box, strict=True)
        ):
            return data
        return data[np.ix_(*rel, np.arange(3))]

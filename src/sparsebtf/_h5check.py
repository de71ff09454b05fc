"""Validated reads of HDF5 inputs: every attribute and dataset is checked (type, dtype, rank,
shape, size against the file and the memory budget) before it is read, and every failure is a
:class:`~sparsebtf.errors.FileFormatError` naming the file, the field and expected vs found.
Used by the dense, model and coded file readers.
"""

from __future__ import annotations

import json
import os
from typing import Any

import h5py
import numpy as np
from h5py import h5z

from ._hdf5 import read_error
from ._limits import check_allocation
from .errors import FileFormatError

__all__ = [
    "HDF5_ERRORS",
    "as_str",
    "checked_dataset",
    "integrity",
    "read_array",
    "read_float_attr",
    "read_int_attr",
    "read_json_attr",
    "read_str_attr",
    "require",
]

#: What h5py raises on damaged files (besides our own errors, which pass through). A
#: MemoryError is not among them: sizes are checked against the memory budget before reading.
HDF5_ERRORS = (OSError, KeyError, RuntimeError, TypeError, ValueError, IndexError, OverflowError)

#: Filters that do not shrink data: a dataset with only these holds all its bytes in the file.
_NON_COMPRESSING = {h5z.FILTER_SHUFFLE, h5z.FILTER_FLETCHER32}
#: Largest expansion of a compressed dataset (DEFLATE's limit is 1032:1).
_MAX_EXPANSION = 1100

_KINDS = {"f": "floating-point", "u": "unsigned integer", "i": "signed integer"}


def as_str(value: Any) -> str:
    """An HDF5 string attribute as ``str`` (h5py may return ``bytes`` or numpy strings)."""
    if isinstance(value, bytes):
        return value.decode()
    if isinstance(value, np.ndarray) and value.shape == ():
        return as_str(value[()])
    return str(value)


def read_json_attr(obj: h5py.HLObject, key: str, where: str) -> dict[str, Any]:
    """Parse a JSON string attribute (absent → ``{}``); errors name the file and field."""
    if key not in obj.attrs:
        return {}
    try:
        out = json.loads(as_str(obj.attrs[key]))
    except (ValueError, TypeError, RecursionError) as e:
        raise FileFormatError(f"{where}: attribute {key!r} is not valid JSON ({e})") from None
    if not isinstance(out, dict):
        raise FileFormatError(f"{where}: attribute {key!r} must hold a JSON object")
    return out


def read_int_attr(
    obj: h5py.HLObject, key: str, where: str, lo: int | None = None, hi: int | None = None
) -> int:
    """An integer attribute, checked to lie in [``lo``, ``hi``] (errors name the field)."""
    if key not in obj.attrs:
        raise FileFormatError(f"{where}: missing attribute {key!r}")
    raw = np.asarray(obj.attrs[key])
    if raw.size != 1 or raw.dtype.kind not in "iu":
        raise FileFormatError(
            f"{where}: attribute {key!r} must be one integer, found {raw.dtype} {raw.shape}"
        )
    value = int(raw.reshape(-1)[0])
    if (lo is not None and value < lo) or (hi is not None and value > hi):
        raise FileFormatError(
            f"{where}: attribute {key!r} is {value}, expected {lo if lo is not None else '-inf'}"
            f"..{hi if hi is not None else 'inf'}"
        )
    return value


def read_float_attr(
    obj: h5py.HLObject, key: str, where: str, default: float | None = None, positive: bool = False
) -> float:
    """A finite float attribute (``default`` when absent, if given)."""
    if key not in obj.attrs:
        if default is None:
            raise FileFormatError(f"{where}: missing attribute {key!r}")
        return default
    raw = np.asarray(obj.attrs[key])
    if raw.size != 1 or raw.dtype.kind not in "fiu":
        raise FileFormatError(
            f"{where}: attribute {key!r} must be one number, found {raw.dtype} {raw.shape}"
        )
    value = float(raw.reshape(-1)[0])
    if not np.isfinite(value) or (positive and value <= 0):
        want = "a finite number > 0" if positive else "a finite number"
        raise FileFormatError(f"{where}: attribute {key!r} is {value}, expected {want}")
    return value


def read_str_attr(obj: h5py.HLObject, key: str, where: str) -> str:
    if key not in obj.attrs:
        raise FileFormatError(f"{where}: missing attribute {key!r}")
    value = obj.attrs[key]
    if isinstance(value, np.ndarray) and value.shape != ():
        raise FileFormatError(f"{where}: attribute {key!r} must be a string, found {value.shape}")
    if not isinstance(value, str | bytes | np.ndarray | np.bytes_ | np.str_):
        raise FileFormatError(f"{where}: attribute {key!r} must be a string, found {value!r}")
    try:
        return as_str(value)
    except UnicodeDecodeError:
        raise FileFormatError(f"{where}: attribute {key!r} is not UTF-8 text") from None


def require(group: h5py.Group, name: str, where: str) -> Any:
    """``group[name]`` or a :class:`FileFormatError` naming the missing dataset/group."""
    groups = ("lights", "views", "stats", "codes", "dictionaries")
    kind = "group" if name in groups else "dataset"
    if not isinstance(group, h5py.Group):
        raise FileFormatError(f"{where}: expected a group, found a dataset")
    if name not in group:
        raise FileFormatError(f"{where}: missing {kind} {name!r}")
    obj = group[name]
    if kind == "group" and not isinstance(obj, h5py.Group):
        raise FileFormatError(f"{where}/{name}: expected a group, found a dataset")
    return obj


def _allowed_bytes(ds: h5py.Dataset) -> int:
    """Most bytes a dataset can hold given the file's size (more when compressed)."""
    available = os.path.getsize(ds.file.filename)
    plist = ds.id.get_create_plist()
    filters = {plist.get_filter(i)[0] for i in range(plist.get_nfilters())}
    return available if filters <= _NON_COMPRESSING else available * _MAX_EXPANSION


def checked_dataset(
    group: h5py.Group,
    name: str,
    where: str,
    kinds: str = "fiu",
    shape: tuple[int | None, ...] | None = None,
    whole: bool = True,
) -> h5py.Dataset:
    """``group[name]`` after checking, without reading it: a dataset, a plain numeric dtype of
    one of ``kinds``, the ``shape`` (None = any length; ``shape=None``: any), and a size the
    file can hold and (``whole``: read at once) the memory budget allows."""
    obj = require(group, name, where)
    here = f"{where}/{name}"
    if not isinstance(obj, h5py.Dataset):
        raise FileFormatError(f"{here}: expected a dataset, found a group")
    dt = obj.dtype
    if dt.kind not in kinds or dt.names is not None or dt.subdtype is not None or dt.itemsize > 8:
        want = " or ".join(_KINDS[k] for k in kinds)
        raise FileFormatError(f"{here}: expected {want} values, found dtype {dt}")
    if shape is not None and (
        len(obj.shape) != len(shape)
        or any(w is not None and w != s for w, s in zip(shape, obj.shape, strict=True))
    ):
        want = "(" + ", ".join("n" if w is None else str(w) for w in shape) + ")"
        raise FileFormatError(f"{here}: expected shape {want}, found {obj.shape}")
    claimed = int(np.prod(obj.shape, dtype=object)) * int(dt.itemsize)
    allowed = _allowed_bytes(obj)
    if claimed > allowed:
        raise FileFormatError(
            f"{here}: shape {obj.shape} needs {claimed} bytes but the file has "
            f"{os.path.getsize(obj.file.filename)}; the file is damaged"
        )
    if whole:
        check_allocation(claimed, here, FileFormatError)
    return obj


def read_array(
    group: h5py.Group,
    name: str,
    where: str,
    kinds: str = "fiu",
    shape: tuple[int | None, ...] | None = None,
    finite: bool = False,
) -> np.ndarray:
    """A whole dataset after :func:`checked_dataset`; a checksum failure or unreadable data
    is a :class:`FileFormatError` naming the dataset; ``finite`` refuses NaN/Inf."""
    ds = checked_dataset(group, name, where, kinds, shape)
    here = f"{where}/{name}"
    try:
        arr = np.asarray(ds[()])
    except HDF5_ERRORS as e:
        raise read_error(e, here) from None
    if finite and arr.dtype.kind == "f":
        bad = ~np.isfinite(arr)
        if bad.any():
            first = tuple(int(i[0]) for i in np.nonzero(bad))
            raise FileFormatError(
                f"{here}: {int(bad.sum())} NaN/Inf values (first at index {first}); the file "
                "is damaged"
            )
    return arr


def integrity(f: h5py.File) -> str:
    """How the file protects its data: every dataset's checksum filter, or its absence."""
    datasets: list[h5py.Dataset] = []
    f.visititems(lambda _, o: datasets.append(o) if isinstance(o, h5py.Dataset) else None)
    summed = sum(bool(d.fletcher32) for d in datasets if d.size)
    total = sum(1 for d in datasets if d.size)
    if summed == 0:
        return "no checksums (written before schema 2); corruption of the data is not detected"
    return f"fletcher32 checksum on {summed} of {total} non-empty datasets"

"""Helpers shared by the model and coded file readers/writers (not public)."""

from __future__ import annotations

import contextlib
import json
import os
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from .._json import json_default
from ..errors import FileFormatError, SparseBTFError

#: What h5py raises on damaged files (besides our own errors, which pass through).
_HDF5_ERRORS = (
    OSError, KeyError, RuntimeError, TypeError, ValueError, IndexError, OverflowError,
    MemoryError,
)


def to_json(obj: Any) -> str:
    """JSON text of a metadata dict; numpy arrays become lists, numpy scalars Python numbers."""
    return json.dumps(obj, sort_keys=True, default=json_default)


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
    except (ValueError, TypeError) as e:
        raise FileFormatError(f"{where}: attribute {key!r} is not valid JSON ({e})") from None
    if not isinstance(out, dict):
        raise FileFormatError(f"{where}: attribute {key!r} must hold a JSON object")
    return out


def read_int_attr(obj: h5py.HLObject, key: str, where: str) -> int:
    if key not in obj.attrs:
        raise FileFormatError(f"{where}: missing attribute {key!r}")
    try:
        return int(np.asarray(obj.attrs[key]).item())
    except (ValueError, TypeError) as e:
        raise FileFormatError(f"{where}: attribute {key!r} is not an integer ({e})") from None


def read_str_attr(obj: h5py.HLObject, key: str, where: str) -> str:
    if key not in obj.attrs:
        raise FileFormatError(f"{where}: missing attribute {key!r}")
    return as_str(obj.attrs[key])


def require(group: h5py.Group, name: str, where: str) -> Any:
    """``group[name]`` or a :class:`FileFormatError` naming the missing dataset/group."""
    if name not in group:
        groups = ("lights", "views", "stats", "codes", "dictionaries")
        kind = "group" if name in groups else "dataset"
        raise FileFormatError(f"{where}: missing {kind} {name!r}")
    return group[name]


def read_array(group: h5py.Group, name: str, where: str) -> np.ndarray:
    """A whole dataset as an array; a size larger than the (uncompressed) file is corruption."""
    obj = require(group, name, where)
    if not isinstance(obj, h5py.Dataset):
        raise FileFormatError(f"{where}/{name}: expected a dataset, found a group")
    claimed = int(obj.size) * int(obj.dtype.itemsize)
    available = os.path.getsize(obj.file.filename)
    if claimed > available:
        raise FileFormatError(
            f"{where}/{name}: shape {obj.shape} needs {claimed} bytes but the file has "
            f"{available}; the file is damaged"
        )
    return np.asarray(obj[()])


@contextlib.contextmanager
def open_checked(path: Path, fmt: str, versions: tuple[int, ...]) -> Iterator[h5py.File]:
    """Open ``path`` read-only and check its ``format`` and ``schema_version`` attributes.

    Errors raised by h5py/HDF5 while the block runs (not HDF5, truncated, damaged metadata:
    ``OSError``, ``KeyError``, ``RuntimeError``, ``TypeError``, ``ValueError`` …) become a
    :class:`FileFormatError` naming the file. (A few damaged metadata blocks make libhdf5
    itself loop; that cannot be caught from Python.)
    """
    if not path.exists():
        raise FileFormatError(f"{path}: no such file")
    try:
        f = h5py.File(path, "r")
    except OSError as e:
        raise FileFormatError(f"{path}: not a readable HDF5 file, or truncated ({e})") from None
    try:
        with f:
            found = as_str(f.attrs["format"]) if "format" in f.attrs else None
            if found != fmt:
                raise FileFormatError(f"{path}: attribute 'format' is {found!r}, not {fmt!r}")
            version = read_int_attr(f, "schema_version", str(path))
            if version not in versions:
                supported = ", ".join(str(v) for v in versions)
                raise FileFormatError(
                    f"{path}: schema_version {version} is not supported (this reader supports "
                    f"{supported}); upgrade sparsebtf to read it"
                )
            yield f
    except SparseBTFError:
        raise
    except _HDF5_ERRORS as e:
        raise FileFormatError(
            f"{path}: damaged or truncated HDF5 file ({type(e).__name__}: {e})"
        ) from None


def check_geometry(
    mode_sizes: tuple[int, ...], patch: int, n_lights: int, n_views: int, where: str, exc: type
) -> None:
    """Modes 1–4 must be (p, p, L, V); the 5D variant adds colour after them."""
    want = (patch, patch, n_lights, n_views)
    if len(mode_sizes) < 4 or tuple(mode_sizes[:4]) != want:
        raise exc(
            f"{where}: data-point modes {tuple(mode_sizes)} do not match (patch, patch, lights, "
            f"views) = {want}"
        )

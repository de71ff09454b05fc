"""Helpers shared by the model and coded file readers/writers (not public)."""

from __future__ import annotations

import contextlib
import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import h5py

from .._h5check import HDF5_ERRORS, read_int_attr, read_str_attr
from .._hdf5 import open_h5, read_error
from .._json import json_default
from ..errors import FileFormatError, SparseBTFError

__all__ = ["check_geometry", "check_str_param", "check_tau_param", "open_checked", "to_json"]


def to_json(obj: Any) -> str:
    """JSON text of a metadata dict; numpy arrays become lists, numpy scalars Python numbers."""
    return json.dumps(obj, sort_keys=True, default=json_default)


@contextlib.contextmanager
def open_checked(path: Path, fmt: str, versions: tuple[int, ...]) -> Iterator[h5py.File]:
    """Open ``path`` read-only (behind the HDF5 watchdog) and check its ``format`` and
    ``schema_version`` attributes.

    Errors raised by h5py/HDF5 while the block runs (truncated, damaged metadata or data,
    checksum failures: ``OSError``, ``KeyError``, ``RuntimeError``, ``TypeError`` …) become a
    :class:`FileFormatError` naming the file.
    """
    f = open_h5(path)
    try:
        with f:
            found = read_str_attr(f, "format", str(path)) if "format" in f.attrs else None
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
    except HDF5_ERRORS as e:
        raise read_error(e, str(path)) from None


def check_tau_param(params: dict[str, Any], key: str, where: str) -> None:
    """``params[key]``, when present, must map channel names to integers >= 1 (a file's
    ``tau`` / ``tau_train``): other values would fail deep inside the runtime."""
    value = params.get(key)
    if value is None:
        return
    ok = isinstance(value, dict) and all(
        isinstance(k, str) and isinstance(v, int) and not isinstance(v, bool) and v >= 1
        for k, v in value.items()
    )
    if not ok:
        raise FileFormatError(
            f"{where}: attribute 'params_json': {key!r} must map channels to integers >= 1, "
            f"found {str(value)[:80]}"
        )


def check_str_param(params: dict[str, Any], key: str, where: str, choices: Any = None) -> None:
    """``params[key]``, when present, must be a string (one of ``choices`` if given)."""
    value = params.get(key)
    if value is None:
        return
    if not isinstance(value, str) or (choices is not None and value not in choices):
        want = f"one of {tuple(choices)}" if choices is not None else "a string"
        raise FileFormatError(
            f"{where}: attribute 'params_json': {key!r} must be {want}, found {str(value)[:80]}"
        )


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

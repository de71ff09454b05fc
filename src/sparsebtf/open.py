"""Open any BTF a user names: our dense file, a coded file (decoded lazily), a Bonn file, or a
synthetic spec. This module sits above the readers, the storage and the runtime.

Accepted sources:

* ``PATH.h5`` with ``format = "sparsebtf-dense"`` — :class:`DenseFileBTF`;
* ``PATH.h5`` with ``format = "sparsebtf-coded"`` — decoded on demand (needs its model);
* ``PATH.btf`` — a Bonn UBO2014 file (DFMF or FMF), reconstructed lazily from its factors;
* ``PATH.zip`` — a UBO2003 / ATRIUM archive of JPEG or Radiance HDR angular images;
* ``synth:CLASS[+black][:SIZE[:SEED[:DIRECTIONS]]]`` — a cached synthetic material, e.g.
  ``synth:stone:64:1:ubo2014`` (``+black``: true black and high dynamic range).

Which reader a file gets is the format registry's (:mod:`sparsebtf.formats.registry`).
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Mapping
from pathlib import Path

from ._h5check import HDF5_ERRORS, read_str_attr
from ._hdf5 import open_h5, read_error
from .constraints import is_array, wrong_type
from .data.btf import BTF
from .errors import FileFormatError
from .formats.registry import FORMATS, formats_for

__all__ = ["file_format", "open_btf", "parse_synth_spec"]


def file_format(path: str | os.PathLike[str]) -> str:
    """The ``format`` attribute of one of our HDF5 files ("sparsebtf-dense", -model, -coded).

    The file is opened behind the HDF5 watchdog (:func:`sparsebtf._hdf5.open_h5`).
    """
    p = Path(path)
    f = open_h5(p)
    try:
        with f:
            fmt = read_str_attr(f, "format", str(p)) if "format" in f.attrs else None
    except HDF5_ERRORS as e:
        raise read_error(e, str(p)) from None
    if fmt is None:
        raise FileFormatError(f"{p}: no 'format' attribute; not a SparseBTF file")
    return fmt


def parse_synth_spec(spec: str) -> dict[str, object]:
    """``synth:CLASS[+black][:SIZE[:SEED[:DIRECTIONS]]]`` → keyword arguments of
    ``synth.cached`` (``+black``: the true-black, high-dynamic-range variant)."""
    parts = spec.split(":")[1:]
    if not parts or not parts[0]:
        raise FileFormatError(f"{spec!r}: expected synth:CLASS[:SIZE[:SEED[:DIRECTIONS]]]")
    material, plus, variant = parts[0].partition("+")
    if plus and variant != "black":
        raise FileFormatError(f"{spec!r}: unknown variant +{variant} (known: +black)")
    out: dict[str, object] = {"material": material}
    if plus:
        out["black"] = True
    try:
        if len(parts) > 1:
            out["size"] = int(parts[1])
        if len(parts) > 2:
            out["seed"] = int(parts[2])
    except ValueError:
        raise FileFormatError(f"{spec!r}: SIZE and SEED must be integers") from None
    if len(parts) > 3:
        out["directions"] = parts[3]
    return out


#: What one BTF may be, in a refusal, and how an array becomes one.
BTF_ARGUMENT = "a BTF, a path or a synth: spec"
ARRAY_HINT = ("an array is no BTF: wrap it as sparsebtf.data.btf.ArrayBTF(data, lights, views) "
              "with the directions of sparsebtf.data.directions (ubo2014() …)")


def array_hint(value: object) -> str:
    """:data:`ARRAY_HINT` where ``value`` is an array (how to wrap it), else nothing."""
    return ARRAY_HINT if is_array(value) else ""


def check_btf(function: str, argument: str, value: object) -> None:
    """Refuse ``value`` unless it is one BTF: a :class:`~sparsebtf.data.btf.BTF`, a path or a
    ``synth:`` spec (an array is named as such, with how to wrap it)."""
    if not isinstance(value, BTF | str | os.PathLike):
        raise wrong_type(function, argument, BTF_ARGUMENT, value, array_hint(value))


def check_btf_list(function: str, argument: str, value: object, expected: str) -> list:
    """``value`` as a list of BTFs, each checked by :func:`check_btf`; an array, bytes, a
    mapping or anything not iterable is refused as a whole (``expected``: what it must be)."""
    if is_array(value) or isinstance(value, bytes | Mapping) or not isinstance(value, Iterable):
        raise wrong_type(function, argument, expected, value, array_hint(value))
    out = list(value)
    for i, one in enumerate(out):
        check_btf(function, f"{argument}[{i}]", one)
    return out


def open_btf(
    source: str | os.PathLike[str],
    model_path: str | os.PathLike[str] | None = None,
    progress: bool | None = None,
) -> BTF:
    """Open ``source`` as a :class:`BTF` (see the module docstring for what is accepted);
    a file's BTF has ``source`` = the path, so messages name the file, not the material."""
    if not isinstance(source, str | os.PathLike) or not isinstance(
            model_path, str | os.PathLike | None):  # fmt: skip
        if not isinstance(source, str | os.PathLike):
            raise wrong_type("open_btf", "source", "a path or a synth: spec", source,
                             array_hint(source))
        raise wrong_type("open_btf", "model_path", "a model file's path or None", model_path)
    s = str(source)
    if s.startswith("synth:"):
        from .data.synth import cached

        return cached(**parse_synth_spec(s), progress=progress)  # type: ignore[arg-type]
    btf = _open_file(s, model_path)
    btf.source = s
    return btf


def _open_file(s: str, model_path: str | os.PathLike[str] | None) -> BTF:
    """The reader :data:`~sparsebtf.formats.registry.FORMATS` gives ``s``'s extension; where
    several share it (or none is registered), the HDF5 ``format`` attribute decides."""
    candidates = [f for f in formats_for(s) if f.reader is not None]
    if len(candidates) == 1 and candidates[0].hdf5_format is None:
        return candidates[0].reader(s, model_path)  # type: ignore[misc]
    fmt = file_format(s)
    for f in FORMATS:
        if f.hdf5_format == fmt and f.reader is not None:
            return f.reader(s, model_path)  # type: ignore[no-any-return]
    raise FileFormatError(f"{s}: format {fmt!r} is not a BTF (dense or coded) file")

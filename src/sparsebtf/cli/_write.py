"""Writing a BTF where a command's ``-o`` says, through the format registry
(:mod:`sparsebtf.formats.registry`): ``.h5``/``.hdf5`` our dense file, ``.btf`` a UBO2014 file
(exact DFMF); any other extension is refused before any work. The file's size is
said before it is written (:class:`._output.Written`)."""

from __future__ import annotations

from typing import Any

from ..formats.registry import writer_for
from ._args import output_format
from ._output import Written

__all__ = ["check_btf_output", "write_btf"]


def check_btf_output(path: str | None, flag: str = "-o") -> str | None:
    """The kind of file ``path`` asks for ("dense" or "ubo2014"), or a one-line refusal
    (:data:`._args.OUTPUT_FORMATS`, the rule every command's outputs follow)."""
    return output_format(path, "btf", flag)


def write_btf(path: str, btf: Any, dtype: str, say: Written, **options: Any) -> None:
    """Write ``btf`` to ``path`` as its extension says (the format registry's writer,
    :func:`sparsebtf.formats.registry.writer_for`), announcing the size first; ``options`` go
    to the writer (the dense file's e.g. ``by="regions"``; a format ignores those it lacks)."""
    kind = check_btf_output(path)
    fmt = writer_for(path)
    shape = f"{btf.height}x{btf.width} texels, {len(btf.lights)} lights x {len(btf.views)} views"
    if fmt.nbytes is not None:
        what = fmt.summary(shape, dtype) if fmt.summary is not None else f"{shape}, {dtype}"
        say.announce(path, fmt.nbytes(btf, dtype), what)
    fmt.writer(path, btf, dtype, **options)  # type: ignore[misc]
    say.wrote(path, f"{shape} ({btf.lights.name})", kind=kind, shape=list(btf.shape),
              dtype=dtype)  # fmt: skip

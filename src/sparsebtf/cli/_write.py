"""Writing a BTF where a command's ``-o`` says: ``.h5``/``.hdf5`` our dense file, ``.btf`` a
UBO2014 file (exact DFMF); any other extension is refused before any work. The file's size is
said before it is written (:class:`._output.Written`); the writing is the library's
:func:`sparsebtf.save.save_btf`."""

from __future__ import annotations

from typing import Any

from ._args import output_format
from ._output import Written, dense_bytes

__all__ = ["check_btf_output", "write_btf"]


def check_btf_output(path: str | None, flag: str = "-o") -> str | None:
    """The kind of file ``path`` asks for ("dense" or "ubo2014"), or a one-line refusal
    (:data:`._args.OUTPUT_FORMATS`, the rule every command's outputs follow)."""
    return output_format(path, "btf", flag)


def write_btf(path: str, btf: Any, dtype: str, say: Written, **dense: Any) -> None:
    """Write ``btf`` to ``path`` as its extension says, announcing the size first; ``dense``
    goes to :func:`~sparsebtf.data.dense_file.write_dense` (e.g. ``by="regions"``)."""
    from ..save import save_btf

    kind = check_btf_output(path)
    shape = f"{btf.height}x{btf.width} texels, {len(btf.lights)} lights x {len(btf.views)} views"
    if kind == "ubo2014":
        from ..formats.ubo2014_write import ubo2014_bytes

        scalar = "half" if dtype == "float16" else "float"
        say.announce(path, ubo2014_bytes(btf.height, btf.width, len(btf.lights),
                                         len(btf.views), scalar),
                     f"UBO2014 DFMF, {shape}, {dtype}")  # fmt: skip
    else:
        say.announce(path, dense_bytes(btf, dtype), f"{shape}, {dtype}")
    # the library's writer (sparsebtf.save_btf); the CLI adds the size said before and after
    save_btf(btf, path, dtype=dtype, progress=None, **dense)
    say.wrote(path, f"{shape} ({btf.lights.name})", kind=kind, shape=list(btf.shape),
              dtype=dtype)  # fmt: skip

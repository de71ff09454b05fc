"""Writing a BTF where a command's ``-o`` says: ``.h5``/``.hdf5`` our dense file, ``.btf`` a
UBO2014 file (exact DFMF); any other extension is refused before any work. The file's size is
said before it is written (:class:`._output.Written`)."""

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
    kind = check_btf_output(path)
    shape = f"{btf.height}x{btf.width} texels, {len(btf.lights)} lights x {len(btf.views)} views"
    if kind == "ubo2014":
        from ..formats.ubo2014_write import ubo2014_bytes, write_btf_ubo2014

        scalar = "half" if dtype == "float16" else "float"
        say.announce(path, ubo2014_bytes(btf.height, btf.width, len(btf.lights),
                                         len(btf.views), scalar),
                     f"UBO2014 DFMF, {shape}, {dtype}")  # fmt: skip
        write_btf_ubo2014(path, btf, scalar)
    else:
        from ..data.dense_file import write_dense

        say.announce(path, dense_bytes(btf, dtype), f"{shape}, {dtype}")
        write_dense(path, btf, dtype=dtype, progress=None, **dense)
    say.wrote(path, f"{shape} ({btf.lights.name})", kind=kind, shape=list(btf.shape),
              dtype=dtype)  # fmt: skip

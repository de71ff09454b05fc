"""Write a BTF or a coded BTF where a path says: the counterpart of
:func:`~sparsebtf.open.open_btf`.

By extension (:func:`save_format`, the one place that decides):

* a :class:`~sparsebtf.model.CodedBTF` to ``.h5`` / ``.hdf5`` — a coded file
  (:func:`~sparsebtf.storage.save_coded`), which ``open_btf`` decodes lazily;
* any other :class:`~sparsebtf.data.btf.BTF` to ``.h5`` / ``.hdf5`` — our dense file
  (:func:`~sparsebtf.data.dense_file.write_dense`, streamed);
* a BTF to ``.btf`` — a UBO2014 DFMF file that reads back to the same values
  (:func:`~sparsebtf.formats.ubo2014_write.write_btf_ubo2014`).

Every other extension (and a coded BTF to ``.btf``) is refused in one line before anything is
read or written; every writer writes atomically (an interrupted write leaves no file).

>>> save_btf(btf, "stone.h5")                           # doctest: +SKIP
>>> save_btf(coded, "stone.coded.h5")                   # doctest: +SKIP
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING, Any

from .errors import BTFInputError

if TYPE_CHECKING:
    from .data.btf import BTF
    from .model import CodedBTF

__all__ = ["save_btf", "save_format"]



def save_format(obj: Any, path: str | os.PathLike[str]) -> str:
    """What :func:`save_btf` writes ``obj`` to ``path`` as: "coded", "dense" or "ubo2014";
    one line (:class:`~sparsebtf.errors.BTFInputError`) for any other extension or object."""
    from .data.btf import BTF
    from .formats.registry import output_extensions
    from .model import CodedBTF

    ext = Path(path).suffix.lower()
    coded = isinstance(obj, CodedBTF)
    if not (coded or isinstance(obj, BTF)):
        raise BTFInputError(f"{path}: save_btf writes a BTF or a coded BTF, not a "
                            f"{type(obj).__name__} (a model: sparsebtf.storage.save_model)")
    # the format registry says which extensions a BTF and a coded BTF are written as
    as_btf = output_extensions("btf")[0].get(ext)
    as_coded = output_extensions("coded")[0].get(ext)
    if as_btf is None and as_coded is None:
        have = ".h5/.hdf5 (a coded file)" if coded else (
            ".h5/.hdf5 (our dense file) or .btf (a UBO2014 file)")  # fmt: skip
        raise BTFInputError(f"{path}: cannot write a {'coded ' if coded else ''}BTF as "
                            f"{ext or 'a file without an extension'}; give {have}")
    if coded and as_coded is None:
        raise BTFInputError(f"{path}: a coded BTF is written as a coded .h5 file; to write "
                            f"{ext}, decode it first: save_btf(decode(coded), {str(path)!r})")
    return as_coded if coded else as_btf  # type: ignore[return-value]


def save_btf(
    btf: BTF | CodedBTF,
    path: str | os.PathLike[str],
    *,
    dtype: str = "float32",
    progress: bool | None = None,
    **options: Any,
) -> Path:
    """Write ``btf`` to ``path`` as its extension says (module docstring); the path written.

    ``dtype`` ("float32" or "float16") is the stored values' type of a dense or UBO2014 file
    (a coded file stores binary16 coefficients whatever it is). ``options`` go to the writer:
    ``chunks``, ``attrs``, ``by`` of :func:`~sparsebtf.data.dense_file.write_dense` (a decoded
    BTF streams ``by="regions"`` unless told), ``schema`` of
    :func:`~sparsebtf.storage.save_coded`; the UBO2014 writer takes none.
    """
    kind = save_format(btf, path)
    if dtype not in ("float32", "float16"):
        raise BTFInputError(f"{path}: dtype must be 'float32' or 'float16', not {dtype!r}")
    if kind == "coded":
        from .storage import save_coded

        return save_coded(btf, path, **options)  # type: ignore[arg-type]
    if kind == "ubo2014" and options:
        raise BTFInputError(f"{path}: the UBO2014 writer takes no options, got "
                            f"{', '.join(sorted(options))}")  # fmt: skip
    if kind == "dense":
        from .runtime.dense import DecodedBTF

        # A decoded BTF decodes whole data points (every direction of a patch): by region.
        options.setdefault("by", "regions" if isinstance(btf, DecodedBTF) else "views")
    from .formats.registry import writer_for

    writer_for(path).writer(str(path), btf, dtype, progress=progress, **options)  # type: ignore[misc]
    return Path(path)

"""Every file format by extension: what it holds, how it is read, written and fuzzed.

One declarative table, :data:`FORMATS`, read by :func:`sparsebtf.open.open_btf` (which reader),
the command line's output checks (``cli/_args.output_format``: which extensions an output of
a role may have, and the one-line refusal naming them), the BTF writer behind ``-o``
(:func:`writer_for`) and the fuzz harness (:mod:`sparsebtf.testing`: which readers, from
which seed files). A new format is one :class:`Format` row (or :func:`register` at run time).

Several formats may share an extension (``.h5`` holds our dense, model and coded files); those
carry the HDF5 ``format`` attribute that tells them apart (:attr:`Format.hdf5_format`).

Readers, writers and corpus makers are imported when first called, so this table imports no
reader: it sits below every layer it names.
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ..errors import SparseBTFError

__all__ = [
    "FORMATS",
    "OUTPUT_FORMATS",
    "Format",
    "by_kind",
    "formats_for",
    "fuzz_readers",
    "output_extensions",
    "register",
    "registered",
    "writer_for",
]

#: ``reader(path, model_path) -> BTF``
Reader = Callable[[str, Any], Any]
#: ``writer(path, btf, dtype, **options)``; options a format does not use are ignored
Writer = Callable[..., Any]
#: ``corpus(folder, shared) -> [seed files]``; ``shared`` carries objects between makers
Corpus = Callable[[Path, dict[str, Any]], list[Path]]


@dataclass(frozen=True)
class Format:
    """One file format.

    kind : its name ("dense", "ubo2014" …), what :func:`~sparsebtf.cli._args.output_format`
        returns for it and the fuzz harness's reader name.
    extensions : lower-case suffixes, the first one named in messages.
    note : what the file is, in an output refusal (``.h5 (our dense file)``).
    roles : the outputs it may be written as ("btf", "dense", "coded", "model", "png", "npz").
    reader : opens it as a BTF, or None (not a BTF: a model, an image, a folder's member).
    writer : writes a BTF in it, or None.
    nbytes : ``nbytes(btf, dtype)``, the size a write will have (said before writing).
    summary : ``summary(shape_text, dtype)``, what a write announces beside its size.
    corpus : makes the fuzz harness's valid seed files (a maker, or the name of one in
        :mod:`sparsebtf.testing.corpus`), or None (not fuzzed).
    hdf5_format : the HDF5 ``format`` attribute that tells it apart from others sharing an
        extension, or None.
    """

    kind: str
    extensions: tuple[str, ...]
    note: str
    roles: tuple[str, ...] = ()
    reader: Reader | None = None
    writer: Writer | None = None
    nbytes: Callable[[Any, str], int] | None = None
    summary: Callable[[str, str], str] | None = None
    corpus: Corpus | str | None = None
    hdf5_format: str | None = None


# --------------------------------------------------------------------------- adapters


def _read_dense(path: str, model_path: Any = None) -> Any:
    from ..data.dense_file import DenseFileBTF

    return DenseFileBTF(path)


def _read_coded(path: str, model_path: Any = None) -> Any:
    from ..patch_tree import AdaptiveCodedBTF
    from ..runtime.adaptive import decoded_view
    from ..runtime.dense import coded_btf_view
    from ..storage import load_coded_with_model

    coded = load_coded_with_model(path, model_path, adaptive=True)
    return decoded_view(coded) if isinstance(coded, AdaptiveCodedBTF) else coded_btf_view(coded)


def _read_ubo2014(path: str, model_path: Any = None) -> Any:
    from .ubo2014 import read_ubo2014

    return read_ubo2014(path)


def _read_ubo2003(path: str, model_path: Any = None) -> Any:
    from .ubo2003 import read_ubo2003_zip

    return read_ubo2003_zip(path)


def _write_dense(path: str, btf: Any, dtype: str = "float32", **options: Any) -> None:
    from ..data.dense_file import write_dense

    write_dense(path, btf, dtype=dtype, progress=options.pop("progress", None),
                **{k: v for k, v in options.items() if k in ("by", "chunks", "attrs")})  # fmt: skip


def _write_ubo2014(path: str, btf: Any, dtype: str = "float32", **options: Any) -> None:
    from .ubo2014_write import write_btf_ubo2014

    write_btf_ubo2014(path, btf, _ubo2014_scalar(dtype))


def _ubo2014_scalar(dtype: str) -> str:
    return "half" if dtype == "float16" else "float"


def _dense_nbytes(btf: Any, dtype: str) -> int:
    from ..data.dense_file import dense_file_bytes

    return dense_file_bytes(btf.shape, dtype)


def _ubo2014_nbytes(btf: Any, dtype: str) -> int:
    from .ubo2014_write import ubo2014_bytes

    return ubo2014_bytes(btf.height, btf.width, len(btf.lights), len(btf.views),
                         _ubo2014_scalar(dtype))  # fmt: skip


#: The built-in formats, in the fuzz harness's report order (its cases' seeds depend on it).
FORMATS: list[Format] = [
    Format("ubo2014", (".btf",), "a UBO2014 file", ("btf",), _read_ubo2014, _write_ubo2014,
           _ubo2014_nbytes, lambda shape, dtype: f"UBO2014 DFMF, {shape}, {dtype}",
           "corpus_ubo2014"),
    Format("ubo2003", (".zip",), "a UBO2003 / ATRIUM archive", (), _read_ubo2003,
           corpus="corpus_ubo2003"),
    Format("dense", (".h5", ".hdf5"), "our dense file", ("btf", "dense"), _read_dense,
           _write_dense, _dense_nbytes, lambda shape, dtype: f"{shape}, {dtype}",
           "corpus_dense", hdf5_format="sparsebtf-dense"),
    Format("model", (".h5", ".hdf5"), "a model file is HDF5", ("model",),
           corpus="corpus_model", hdf5_format="sparsebtf-model"),
    Format("coded", (".h5", ".hdf5"), "a coded file is HDF5", ("coded",), _read_coded,
           corpus="corpus_coded", hdf5_format="sparsebtf-coded"),
    Format("release", (".bin",), "the authors' release files", (),
           corpus="corpus_release"),
    Format("png", (".png",), "the image is written as PNG", ("png",)),
    Format("npz", (".npz",), "NumPy arrays, np.load reads them", ("npz",)),
]  # fmt: skip


def register(fmt: Format) -> None:
    """Add ``fmt`` (after the built-in formats); a kind already registered is refused."""
    if any(f.kind == fmt.kind for f in FORMATS):
        raise ValueError(f"format {fmt.kind!r} is already registered")
    FORMATS.append(fmt)


@contextlib.contextmanager
def registered(fmt: Format) -> Iterator[Format]:
    """``fmt`` registered for the ``with`` block only (tests, plug-ins tried out)."""
    register(fmt)
    try:
        yield fmt
    finally:
        FORMATS.remove(fmt)


def by_kind(kind: str) -> Format:
    """The format named ``kind``."""
    for f in FORMATS:
        if f.kind == kind:
            return f
    raise KeyError(kind)


def formats_for(path: str | os.PathLike[str]) -> list[Format]:
    """The formats whose extensions include ``path``'s (case-insensitive), in table order."""
    suffix = Path(path).suffix.lower()
    return [f for f in FORMATS if suffix in f.extensions]


def fuzz_readers() -> tuple[str, ...]:
    """The formats the fuzz harness exercises (those with a corpus maker), in table order."""
    return tuple(f.kind for f in FORMATS if f.corpus is not None)


def output_extensions(role: str) -> tuple[dict[str, str], str]:
    """For an output of ``role``: extension → kind, and the text naming the extensions to
    give (``.h5 (our dense file) or .btf (a UBO2014 file)``)."""
    # ours (the HDF5 formats) are named first, then the others in table order
    formats = sorted((f for f in FORMATS if role in f.roles), key=lambda f: f.hdf5_format is None)
    if not formats:
        raise KeyError(role)
    table = {ext: f.kind for f in formats for ext in f.extensions}
    return table, " or ".join(f"{f.extensions[0]} ({f.note})" for f in formats)


class _OutputFormats(Mapping[str, tuple[dict[str, str], str]]):
    """role → :func:`output_extensions`, computed from :data:`FORMATS` at each look-up (so a
    format registered later is seen)."""

    def __getitem__(self, role: str) -> tuple[dict[str, str], str]:
        return output_extensions(role)

    def __iter__(self) -> Iterator[str]:
        return iter(dict.fromkeys(r for f in FORMATS for r in f.roles))

    def __len__(self) -> int:
        return sum(1 for _ in self)


#: role → (extension → kind, extensions named in a refusal), the rule every output follows.
OUTPUT_FORMATS: Mapping[str, tuple[dict[str, str], str]] = _OutputFormats()


def writer_for(path: str | os.PathLike[str], role: str = "btf") -> Format:
    """The format a BTF written to ``path`` takes (its :attr:`Format.writer` writes it), or a
    one-line refusal naming the extensions that have a writer."""
    table, names = output_extensions(role)
    suffix = Path(path).suffix.lower()
    kind = table.get(suffix)
    fmt = by_kind(kind) if kind is not None else None
    if fmt is None or fmt.writer is None:
        raise SparseBTFError(f"{path}: unknown extension {suffix or '(none)'!r}; give {names}")
    return fmt

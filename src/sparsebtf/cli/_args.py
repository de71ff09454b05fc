"""Arguments several commands share: opening a BTF (with ``--crop``), checking ``--tau``,
choosing where the work runs (``--workers`` / ``--scheduler``) and naming outputs."""

from __future__ import annotations

import argparse
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from ..errors import SparseBTFError

__all__ = [
    "add_cluster_options",
    "check_tau",
    "cluster_options",
    "open_source",
    "output_files",
    "parse_crop",
]


def parse_crop(text: str | None) -> tuple[slice, slice] | None:
    """``--crop R0:R1,C0:C1`` → (row slice, column slice), or None."""
    if not text:
        return None
    try:
        r, c = text.split(",")
        r0, r1 = (int(x) for x in r.split(":"))
        c0, c1 = (int(x) for x in c.split(":"))
    except ValueError:
        raise SparseBTFError(f"--crop must look like R0:R1,C0:C1, got {text!r}") from None
    return slice(r0, r1), slice(c0, c1)


def open_source(source: str, model: str | None = None, crop: str | None = None) -> Any:
    """The BTF a command argument names (``sparsebtf.open.open_btf``), cropped if asked."""
    from ..open import open_btf

    btf = open_btf(source, model)
    window = parse_crop(crop)
    if window is not None:
        from ..data.crop import CroppedBTF

        btf = CroppedBTF(btf, *window)
    return btf


def check_tau(text: str | None, flag: str = "--tau") -> str | None:
    """``--tau`` as given, after checking its syntax with the one τ parser
    (:func:`sparsebtf.model.parse_tau`): an error names the flag."""
    if text is None:
        return None
    from ..model import CHANNELS, parse_tau

    ones = dict.fromkeys(CHANNELS, 1)
    try:
        parse_tau(text, CHANNELS, full=ones, nominal=ones)
    except SparseBTFError:
        raise SparseBTFError(
            f"{flag} must be 'Y,U,V' integers (e.g. 885,64,64), one integer for every channel, "
            f"or a fraction in (0, 1) of the coded tau (e.g. 0.25); got {text!r}"
        ) from None
    return text


def _worker_count(text: str) -> int:
    try:
        n = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number of workers, got {text!r}") from None
    if n < 1:
        raise argparse.ArgumentTypeError(f"must be >= 1, got {n}")
    return n


def add_cluster_options(parser: argparse.ArgumentParser) -> None:
    """``--workers N`` (a local Dask cluster) and ``--scheduler ADDRESS`` (a running one)."""
    from ..execution import SCHEDULER_ENV

    g = parser.add_mutually_exclusive_group()
    g.add_argument(
        "--workers", type=_worker_count, default=None, metavar="N",
        help="run on a local Dask cluster of N single-threaded worker processes",
    )  # fmt: skip
    g.add_argument(
        "--scheduler", default=None, metavar="ADDRESS",
        help=f"run on the Dask cluster of this scheduler (e.g. tcp://10.0.0.5:8786; default: "
        f"${SCHEDULER_ENV} if set, else this process; see docs/distributed.md)",
    )  # fmt: skip


def cluster_options(args: argparse.Namespace) -> dict[str, Any]:
    """The ``workers`` / ``scheduler`` keywords of the Python API from the parsed options."""
    return {"workers": args.workers, "scheduler": args.scheduler}


def output_files(sources: Sequence[str], output: str) -> list[Path]:
    """Where each input's output goes: ``output`` itself (one input), or
    ``output/NAME.coded.h5`` (:func:`sparsebtf.codec.output_name`) when ``output`` is a folder:
    ``DIR/``, an existing folder, or, for several inputs, a name without ``.h5``. Two inputs
    may not share an output, nor an output overwrite an input."""
    from ..codec.many import output_name

    file_like = output.lower().endswith((".h5", ".hdf5"))
    folder = output.endswith(("/", os.sep)) or Path(output).is_dir()
    if len(sources) > 1 and not folder:
        if file_like:
            raise SparseBTFError(
                f"{len(sources)} inputs need an output folder (-o DIR/), not the file {output}"
            )
        folder = True
    paths = [Path(output) / output_name(s) for s in sources] if folder else [Path(output)]
    seen: dict[Path, str] = {}
    for s, p in zip(sources, paths, strict=True):
        key = p.absolute()
        if key in seen:
            raise SparseBTFError(f"{seen[key]} and {s} would both be written to {p}")
        if not s.startswith("synth:") and Path(s).absolute() == key:
            raise SparseBTFError(f"{s}: its output {p} would overwrite the input")
        seen[key] = s
    return paths

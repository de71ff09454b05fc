"""Arguments several commands share: opening a BTF (with ``--crop``), checking ``--tau``, the
numeric options (finite, in range, units in the message), output paths (a file named as its
kind is written, :data:`OUTPUT_FORMATS`, in a folder that can be written, not one of the inputs;
one file per input in a folder) and where the work runs (``--workers`` / ``--scheduler``).
Every output is checked before any work starts.

Numeric checks are declared beside each command's options, ``s.set_defaults(checks={...})``
with :func:`number` / :func:`integer`, and run by :func:`check_args` before the command; the
options of the library's option objects (``encode``, ``train``) are checked by the objects
themselves (:func:`build_options`: the library's constraint table, the flag named). Every
failure is one ``sparsebtf: error: …`` line (exit 2), in the words of
:mod:`sparsebtf.constraints`.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import sys
import tempfile
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any, TypeVar

from ..constraints import Interval, Options, check_option
from ..errors import OptionError, SparseBTFError
from ..formats.registry import OUTPUT_FORMATS as _REGISTRY_OUTPUTS

__all__ = [
    "OUTPUT_FORMATS",
    "add_cluster_options",
    "add_deprecated_alias",
    "build_options",
    "check_args",
    "check_output_dir",
    "check_output_file",
    "check_tau",
    "cluster_options",
    "integer",
    "number",
    "open_source",
    "option_checks",
    "output_files",
    "output_format",
    "parse_crop",
]

Check = Callable[[Any, str], None]
_O = TypeVar("_O", bound=Options)


def number(
    lo: float | None = None,
    hi: float | None = None,
    *,
    lo_open: bool = False,
    hi_open: bool = False,
    unit: str = "",
) -> Check:
    """A check that a float option is finite and in [lo, hi] (open ends with ``*_open``): an
    :class:`~sparsebtf.constraints.Interval`, the library's own constraint."""
    closed = {(False, False): "both", (False, True): "left", (True, False): "right",
              (True, True): "neither"}[lo_open, hi_open]  # fmt: skip
    rule = [Interval(float, lo, hi, closed=closed, unit=unit)]  # type: ignore[arg-type]
    return lambda value, flag: check_option(flag, value, rule)


def integer(lo: int | None = None, hi: int | None = None, *, unit: str = "") -> Check:
    """A check that an integer option lies in [lo, hi] (an :class:`Interval` of integers)."""
    rule = [Interval(int, lo, hi, unit=unit)]
    return lambda value, flag: check_option(flag, value, rule)


class _GivenInt(int):
    """An integer the user typed: never the very object of an equal default, which argparse's
    mutually exclusive groups skip (``--candidates 2 --exhaustive`` went through, and
    ``--candidates`` was lost, when 2 was the default)."""


def given_int(text: str) -> int:
    """``type=`` of an integer option in a mutually exclusive group (see :class:`_GivenInt`);
    :func:`build_options` hands the library a plain int."""
    return _GivenInt(int(text))


given_int.__name__ = "int"  # argparse's "invalid int value: 'x'"


def option_checks(cls: type[Options], flags: Mapping[str, str]) -> dict[str, Check]:
    """The ``checks`` (:func:`check_args`) of the options ``flags`` names (option → flag):
    the library's own constraints (``cls.constraints``), run before the command."""

    def check(name: str) -> Check:
        return lambda value, flag: check_option(flag, value, cls.constraints[name])

    return {flag.lstrip("-").replace("-", "_"): check(name) for name, flag in flags.items()}


def build_options(cls: type[_O], flags: Mapping[str, str], **values: Any) -> _O:
    """The option object ``cls`` (:class:`~sparsebtf.codec.options.EncodeOptions` …) of a
    command's parsed ``values``; its refusal is the library's line naming the flag (``flags``:
    option → flag; else ``--`` + the option's name)."""
    values = {k: int(v) if isinstance(v, _GivenInt) else v for k, v in values.items()}
    try:
        return cls(**values)
    except OptionError as e:
        raise e.renamed(flags.get(e.option, "--" + e.option.replace("_", "-")),
                        dict(flags)) from None


class _DeprecatedAlias(argparse.Action):
    """An old option spelling that still works, with one note naming the new one."""

    def __init__(self, option_strings: list[str], dest: str, *, new: str, why: str,
                 **kwargs: Any) -> None:  # fmt: skip
        super().__init__(option_strings, dest, **kwargs)
        self.new, self.why = new, why

    def __call__(self, parser: Any, namespace: argparse.Namespace, values: Any,
                 option_string: str | None = None) -> None:  # fmt: skip
        print(f"sparsebtf: note: {option_string} is deprecated ({self.why}); use {self.new}",
              file=sys.stderr)  # fmt: skip
        setattr(namespace, self.dest, values)


def add_deprecated_alias(
    parser: argparse.ArgumentParser, old: str, new: str, why: str
) -> None:
    """Let ``old`` keep working as ``new`` (same value, same checks), hidden from ``--help``;
    using it prints ``sparsebtf: note: OLD is deprecated (WHY); use NEW``. One meaning per
    option name across commands: ``--size`` is texels (synth), ``--light`` an index (lookup)."""
    dest = new.lstrip("-").replace("-", "_")
    parser.add_argument(old, dest=dest, action=_DeprecatedAlias, new=new, why=why,
                        default=argparse.SUPPRESS, help=argparse.SUPPRESS)  # fmt: skip


def check_args(args: argparse.Namespace) -> None:
    """Run the checks a command declared with ``set_defaults(checks={dest: check})``."""
    for dest, check in (getattr(args, "checks", None) or {}).items():
        value = getattr(args, dest, None)
        if value is not None:
            check(value, "--" + dest.replace("_", "-"))


# --------------------------------------------------------------------------- output paths


#: What each kind of output file is written as, by extension, and the names to give: one rule
#: for every command that writes (a file under another kind's name would not read back).
#: role → (extension → kind, the extensions named in a refusal): the format registry's
#: (:data:`sparsebtf.formats.registry.OUTPUT_FORMATS`), read at each look-up.
OUTPUT_FORMATS = _REGISTRY_OUTPUTS


def output_format(
    path: str | os.PathLike[str] | None, kind: str, flag: str = "-o", alternative: str = ""
) -> str | None:
    """What ``path`` is written as for an output of ``kind`` (:data:`OUTPUT_FORMATS`: "dense",
    "ubo2014", "coded" …), or a one-line refusal naming the extensions to give (and
    ``alternative``, e.g. a folder). None passes through."""
    if path is None:
        return None
    formats, names = OUTPUT_FORMATS[kind]
    suffix = Path(path).suffix.lower()
    if suffix not in formats:
        raise SparseBTFError(
            f"{flag} {path}: unknown extension {suffix or '(none)'!r}; give {names}{alternative}"
        )
    return formats[suffix]


def _existing_ancestor(path: Path) -> Path:
    for parent in path.parents:
        if parent.exists():
            return parent
    return Path(".")


def _same_file(a: Path, b: Path) -> bool:
    try:
        return a.exists() and b.exists() and os.path.samefile(a, b)
    except OSError:
        return False


def _check_writable(base: Path, p: Path, flag: str) -> None:
    """One line unless a folder can be made in ``base`` (the deepest existing folder of the
    output ``p``). ``os.access`` says yes to root everywhere, also under ``/proc``; making
    (and removing) an empty folder is the test that holds, and leaves nothing behind."""
    if not os.access(base, os.W_OK | os.X_OK):
        raise SparseBTFError(f"{flag} {p}: cannot write into {base} (permission denied or a "
                             "read-only file system)")  # fmt: skip
    try:
        os.rmdir(tempfile.mkdtemp(prefix=".sparsebtf-probe-", dir=base))
    except OSError as e:
        raise SparseBTFError(
            f"{flag} {p}: cannot write into {base}: making a folder there fails "
            f"({e.strerror or e})"
        ) from None


def check_output_file(
    path: str | os.PathLike[str] | None,
    inputs: Iterable[Any] = (),
    flag: str = "-o",
    kind: str | None = None,
) -> Path | None:
    """Check an output file before any work is done: named as its ``kind`` is written
    (:func:`output_format`, when given), not a folder, its folder (made when written, if
    missing) not under a file and writable, and not one of ``inputs`` (which would be
    destroyed). Returns the path (None passes through)."""
    if path is None:
        return None
    p = Path(path)
    if not str(path):
        raise SparseBTFError(f"{flag}: the output path is empty")
    if p.is_dir():
        raise SparseBTFError(f"{flag} {p}: is a folder; give a file name")
    if kind is not None:
        output_format(path, kind, flag)
    base = _existing_ancestor(p)
    if not base.is_dir():
        raise SparseBTFError(f"{flag} {p}: {base} is a file, not a folder")
    _check_writable(base, p, flag)
    for item in inputs:
        if item is None or str(item).startswith("synth:"):
            continue
        if _same_file(p, Path(item)):
            raise SparseBTFError(
                f"{flag} {p} is also an input ({item}); writing it would destroy the input: "
                "choose another output name"
            )
    return p


def check_output_dir(path: str | os.PathLike[str] | None, flag: str) -> Path | None:
    """Check an output folder: not an existing file, and creatable/writable."""
    if path is None:
        return None
    p = Path(path)
    if p.exists() and not p.is_dir():
        raise SparseBTFError(f"{flag} {p}: is a file, not a folder")
    base = p if p.exists() else _existing_ancestor(p)
    if not base.is_dir():
        raise SparseBTFError(f"{flag} {p}: {base} is a file, not a folder")
    _check_writable(base, p, flag)
    return p


def checkpoint_dir(args: argparse.Namespace) -> Path:
    """``--checkpoint-dir``, or ``OUTPUT.checkpoint`` beside the output (file or folder)."""
    if args.checkpoint_dir:
        return Path(args.checkpoint_dir)
    out = Path(args.output)
    return out.with_name(out.name + ".checkpoint")


def check_resume(folder: Path, resume: bool, pattern: str, command: str) -> None:
    """A run starts clean or resumes on purpose, never both by accident: ``--resume`` needs
    checkpoints (files matching ``pattern``) in ``folder``, and checkpoints need ``--resume``."""
    found = (sorted(str(p.relative_to(folder)) for p in folder.glob(pattern))
             if folder.is_dir() else [])  # fmt: skip
    if resume and not found:
        raise SparseBTFError(
            f"--resume: no checkpoint in {folder} (an interrupted 'sparsebtf {command}' with "
            "the same -o, or --checkpoint-dir, leaves one there)"
        )
    if found and not resume:
        shown = ", ".join(found[:3]) + (f" and {len(found) - 3} more" if len(found) > 3 else "")
        raise SparseBTFError(
            f"{folder} holds the checkpoints of an earlier run ({shown}); add "
            "--resume to continue it, or delete the folder to start over"
        )


@contextlib.contextmanager
def resumable(folder: Path) -> Iterator[None]:
    """Run work that checkpoints into ``folder``: on any failure an empty folder (nothing to
    resume from) is removed, and a lost cluster's one line says how to resume."""
    from ..execution import ClusterError

    try:
        yield
    except BaseException as e:
        if folder.is_dir() and not any(folder.iterdir()):
            folder.rmdir()
        elif isinstance(e, ClusterError):
            raise ClusterError(f"{e}; rerun with --resume to continue from {folder}") from None
        raise


# --------------------------------------------------------------------------- BTF sources


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
    """The BTF a command argument names (``sparsebtf.open.open_btf``), cropped if asked.

    The crop must lie inside the BTF: no clipping, no negative (from-the-end) indices.
    """
    from ..open import open_btf

    window = parse_crop(crop)
    btf = open_btf(source, model)
    if window is not None:
        from ..data.crop import CroppedBTF

        (r0, r1), (c0, c1) = ((w.start, w.stop) for w in window)
        if not (0 <= r0 < r1 <= btf.height and 0 <= c0 < c1 <= btf.width):
            raise SparseBTFError(
                f"--crop {crop}: rows R0:R1 and columns C0:C1 must satisfy 0 <= R0 < R1 <= "
                f"{btf.height} and 0 <= C0 < C1 <= {btf.width} ({source} is {btf.height}x"
                f"{btf.width} texels)"
            )
        btf = CroppedBTF(btf, *window)
    return btf


def check_tau(text: str | None, flag: str = "--tau") -> str | None:
    """``--tau`` as given, after checking its syntax with the one τ parser
    (:func:`sparsebtf.model.parse_tau`): an error names the flag."""
    if text is None:
        return None
    from ..model import CHANNELS, parse_tau

    ones = dict.fromkeys(CHANNELS, 1)
    if not text.strip():
        raise SparseBTFError(
            f"{flag} must be 'Y,U,V' integers (e.g. 885,64,64), one integer for every channel, "
            f"or a fraction in (0, 1) of the coded tau (e.g. 0.25); got {text!r}"
        )
    try:
        parse_tau(text, CHANNELS, full=ones, nominal=ones)
    except SparseBTFError as e:
        raise SparseBTFError(f"{flag}: {e}") from None
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


def output_files(
    sources: Sequence[str], output: str, inputs: Sequence[str | None] = ()
) -> list[Path]:
    """Where each input's output goes: ``output`` itself (one input), or
    ``output/NAME.coded.h5`` (:func:`sparsebtf.codec.output_name`) when ``output`` is a folder:
    ``DIR/``, an existing folder, or, for several inputs, a name without ``.h5``. Two inputs
    may not share an output, nor an output overwrite an input (or one of ``inputs``)."""
    from ..codec.many import output_name

    file_like = output.lower().endswith((".h5", ".hdf5"))
    folder = output.endswith(("/", os.sep)) or Path(output).is_dir()
    if len(sources) > 1 and not folder:
        if file_like:
            raise SparseBTFError(
                f"{len(sources)} inputs need an output folder (-o DIR/), not the file {output}"
            )
        folder = True
    if folder:
        check_output_dir(output, "-o")
    else:
        output_format(output, "coded", alternative=", or DIR/ for a folder of NAME.coded.h5")
    paths = [Path(output) / output_name(s) for s in sources] if folder else [Path(output)]
    seen: dict[Path, str] = {}
    for s, p in zip(sources, paths, strict=True):
        key = p.absolute()
        if key in seen:
            raise SparseBTFError(f"{seen[key]} and {s} would both be written to {p}")
        if not s.startswith("synth:") and Path(s).absolute() == key:
            raise SparseBTFError(f"{s}: its output {p} would overwrite the input")
        check_output_file(p, [*sources, *inputs], kind="coded")
        seen[key] = s
    return paths


def log_offset(text: str) -> Any:
    """The ``--log-offset`` value: "auto", "release" or a number in [1e-5, 1e3] (the library's
    rule, :data:`~sparsebtf.points.preprocessing.LOG_OFFSET_RULE`, naming the flag)."""
    from ..points.preprocessing import resolve_log_offset

    return resolve_log_offset(text, "--log-offset")

"""The ``sparsebtf`` command: builds the parser from one module per command and dispatches.

Every command has ``--help``; long work shows a progress bar with ETA on a terminal
(``SPARSEBTF_PROGRESS=1`` forces it, ``=0`` silences it); ``--json`` prints one JSON object.
Errors in the user's input print one line ``sparsebtf: error: …`` and exit with status 2;
warnings print as one ``sparsebtf: note: …`` line each (no source line). ``sparsebtf … |
head`` exits 0 when the reader goes away. Text stdout's encoding lacks (a name with é under
``LC_ALL=C`` or ``PYTHONIOENCODING=ascii``, a file name that is not UTF-8) prints as a
backslash escape. Each command module has ``register(subparsers)``;
heavy imports happen inside its ``run``.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import signal
import sys
import warnings
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from typing import Any, NoReturn

from .._version import library_version
from ..errors import SparseBTFError
from . import (
    bench,
    blend,
    cache,
    capture,
    convert,
    decode,
    demo,
    encode,
    evaluate,
    export_release,
    import_release,
    info,
    lookup,
    models,
    render,
    synth,
    train,
    view,
)
from ._args import check_args

__all__ = ["build_parser", "main"]

#: The commands in the order ``sparsebtf --help`` lists them: the pipeline first.
COMMANDS = (
    synth, capture, info, models, train, encode, decode, evaluate, convert, import_release,
    export_release, lookup, demo, blend, render, view, bench, cache,
)  # fmt: skip


class Parser(argparse.ArgumentParser):
    """argparse with one addition to its usage errors: a value that starts with '-' (``--crop
    -10:10,0:10``) reads as an option to argparse, so the error says how to give it."""

    def error(self, message: str) -> NoReturn:
        if message.endswith("expected one argument"):
            flag = message.split(":")[0].removeprefix("argument ").split("/")[-1]
            message += f" (a value that starts with '-' must be attached: {flag}=VALUE)"
        super().error(message)


def build_parser() -> argparse.ArgumentParser:
    p = Parser(
        prog="sparsebtf",
        description="SparseBTF: learn, encode, store and decode Bidirectional Texture Functions "
        "with sparse coefficients on an ensemble of orthonormal 4D dictionaries (EGSR 2023).",
    )
    p.add_argument("--version", action="version", version=f"sparsebtf {library_version()}")
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for module in COMMANDS:
        module.register(sub)
    return p


def _terminate(signum: int, frame: object) -> None:
    # `kill` (SIGTERM) unwinds like Ctrl-C, so temporary outputs are removed on the way out.
    raise SystemExit(128 + signum)


def _note(message: Warning | str) -> None:
    print(f"sparsebtf: note: {message}", file=sys.stderr)


@contextmanager
def _warnings_as_notes() -> Iterator[list[str]]:
    """Warnings as ``sparsebtf: note: …`` lines, without the source line Python adds.

    Numeric RuntimeWarnings (overflow, invalid value) are held back: before a one-line error
    they are noise the error explains; after a success they print once each at the end. The
    list yielded collects them; the caller prints it (:func:`_flush_notes`).
    """
    held: list[str] = []

    def show(message: Warning | str, category: type[Warning], *_: Any, **__: Any) -> None:
        text = str(message)
        if issubclass(category, RuntimeWarning):
            if text not in held:
                held.append(text)
        else:
            _note(text)

    with warnings.catch_warnings():
        warnings.showwarning = show
        yield held


def _stdout_gone() -> int:
    # The reader went away (``sparsebtf info … | head``): what it wanted it has; stop quietly
    # and point stdout at /dev/null so the interpreter's final flush does not complain either.
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, sys.stdout.fileno())
    return 0


@contextmanager
def _printable_output() -> Iterator[None]:
    """stdout and stderr that print every text: a character their encoding lacks (a name
    with é on an ASCII terminal, ``LC_ALL=C``; a file name that is not valid UTF-8, held as
    surrogates) prints as a backslash escape, not a UnicodeEncodeError traceback."""
    changed = []
    for stream in (sys.stdout, sys.stderr):
        errors = getattr(stream, "errors", None)
        if errors in ("strict", None) and hasattr(stream, "reconfigure"):
            try:
                stream.reconfigure(errors="backslashreplace")
            except (ValueError, OSError, AttributeError):  # pragma: no cover - odd streams
                continue
            changed.append((stream, errors or "strict"))
    try:
        yield
    finally:
        for stream, errors in changed:
            with contextlib.suppress(ValueError, OSError):
                stream.reconfigure(errors=errors)


def main(argv: Sequence[str] | None = None) -> int:
    with _printable_output():
        return _main(argv)


def _main(argv: Sequence[str] | None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        previous = signal.signal(signal.SIGTERM, _terminate)
    except ValueError:  # not the main thread (embedded use): keep the default
        previous = None
    try:
        with _warnings_as_notes() as held:
            check_args(args)
            code = int(args.func(args) or 0)
            sys.stdout.flush()  # a closed pipe shows here, inside the handler below
        for text in held:
            _note(text)
        return code
    except SparseBTFError as e:
        print(f"sparsebtf: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("sparsebtf: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:
        return _stdout_gone()
    except OSError as e:  # the system refused a read or write (a full disk, a lost mount):
        # one line that says what and where, as for bad input; outputs are never half-written
        print(f"sparsebtf: error: {e}", file=sys.stderr)
        return 2
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())

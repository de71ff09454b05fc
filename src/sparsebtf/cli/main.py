"""The ``sparsebtf`` command: builds the parser from one module per command and dispatches.

Every command has ``--help``; long work shows a progress bar with ETA on a terminal
(``SPARSEBTF_PROGRESS=1`` forces it, ``=0`` silences it); ``--json`` prints one JSON object.
Errors in the user's input print one line ``sparsebtf: error: …`` and exit with status 2.
Each command module has ``register(subparsers)``; heavy imports happen inside its ``run``.
"""

from __future__ import annotations

import argparse
import os
import signal
import sys
from collections.abc import Sequence

from ..errors import SparseBTFError
from . import (
    bench,
    blend,
    convert,
    decode,
    demo,
    encode,
    evaluate,
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
    synth, info, models, train, encode, decode, evaluate, convert, import_release, lookup,
    demo, blend, render, view, bench,
)  # fmt: skip


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="sparsebtf",
        description="SparseBTF: learn, encode, store and decode Bidirectional Texture Functions "
        "with sparse coefficients on an ensemble of orthonormal 4D dictionaries (EGSR 2023).",
    )
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for module in COMMANDS:
        module.register(sub)
    return p


def _terminate(signum: int, frame: object) -> None:
    # `kill` (SIGTERM) unwinds like Ctrl-C, so temporary outputs are removed on the way out.
    raise SystemExit(128 + signum)


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        previous = signal.signal(signal.SIGTERM, _terminate)
    except ValueError:  # not the main thread (embedded use): keep the default
        previous = None
    try:
        check_args(args)
        return int(args.func(args) or 0)
    except SparseBTFError as e:
        print(f"sparsebtf: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("sparsebtf: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:
        # The reader went away (``sparsebtf info … | head``): stop quietly, and point stdout
        # at /dev/null so the interpreter's final flush does not complain either.
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        return 1
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())

"""``sparsebtf cache``: list, size and clear the cache of rendered synthetic materials and
captures (:mod:`sparsebtf.data.cache`)."""

from __future__ import annotations

import argparse
import time
from typing import Any

from ._output import print_json

__all__ = ["register"]

DESCRIPTION = """\
Synthetic materials (synth:CLASS inputs, 'sparsebtf demo', the benchmarks) and captured
samples are rendered once into a dense float32 file in the cache and reopened afterwards.

where     $SPARSEBTF_CACHE, else ~/.cache/sparsebtf
how big   H x W x lights x views x 3 x 4 bytes per material: 424 MiB at 400x400 texels and
          UBO2014's 151 x 151 directions, 952 MiB at 600x600; 'sparsebtf demo' leaves about
          4 GB, the quality benchmark more. A write of 64 MiB or more is announced first.
cap       SPARSEBTF_CACHE_MAX=2GB (also 500MiB, 1.5G, or bytes): after each write the least
          recently used entries are removed until the rest fit, never the one just written
          nor one the writing process still uses (a later write removes those).
clear     'sparsebtf cache clear' removes every entry, 'sparsebtf cache clear stone' those
          whose name contains 'stone' (or matches a wildcard such as 'synth-*-600x600-*').
          An entry removed is rendered again when next needed.

Only files the cache writes (synth-*.h5, capture-*.h5) are listed or removed.

  sparsebtf cache                 # the entries, least recently used first, and the total
  sparsebtf cache size --json     # the total as JSON
  sparsebtf cache clear stone     # remove the stone materials
"""


def run(args: argparse.Namespace) -> int:
    from ..data.cache import CACHE_MAX_VARIABLE, cache_cap, check_folder, clear, entries

    folder = check_folder()  # a file in its place: one error line
    cap = cache_cap()
    action = args.action or "list"
    if not folder.exists():  # nothing cached yet: say so, not "0 entries"
        if args.json:
            print_json({"folder": str(folder), "exists": False, "entries": 0,
                        "total_bytes": 0, "cap_bytes": cap})  # fmt: skip
        else:
            print(f"{folder}: no such folder, nothing cached yet (it is made at the first "
                  "synth: or captured input; $SPARSEBTF_CACHE moves it)")  # fmt: skip
        return 0
    if action == "clear":
        removed = clear(args.patterns)
        left = entries()
        summary = {"folder": str(folder), "removed": [e.as_dict() for e in removed],
                   "removed_bytes": sum(e.bytes for e in removed), "entries": len(left),
                   "total_bytes": sum(e.bytes for e in left)}  # fmt: skip
        if args.json:
            print_json(summary)
        else:
            what = f" matching {', '.join(args.patterns)}" if args.patterns else ""
            print(
                f"removed {_entries(len(removed))}{what} ({_size(summary['removed_bytes'])}) "
                f"from {folder}; {len(left)} left ({_size(summary['total_bytes'])})"
            )
        return 0
    found = entries()
    total = sum(e.bytes for e in found)
    cap_text = (f"capped at {_size(cap)} by {CACHE_MAX_VARIABLE}" if cap is not None
                else f"no cap: set {CACHE_MAX_VARIABLE}, e.g. 2GB")  # fmt: skip
    summary = {"folder": str(folder), "entries": len(found), "total_bytes": total,
               "cap_bytes": cap}  # fmt: skip
    if action == "list":
        summary["files"] = [e.as_dict() for e in found]
    if args.json:
        print_json(summary)
        return 0
    print(f"{folder}: {_entries(len(found))}, {_size(total)} ({cap_text})")
    if action == "list":
        for e in found:
            used = time.strftime("%Y-%m-%d %H:%M", time.localtime(e.last_used))
            print(f"  {_size(e.bytes):>10}  {used}  {e.path.name}")
    return 0


def _entries(n: int) -> str:
    return f"{n} {'entry' if n == 1 else 'entries'}"


def _size(n: int | None) -> str:
    from .._limits import format_bytes

    return "none" if n is None else format_bytes(n)


def register(sub: Any) -> None:
    s = sub.add_parser(
        "cache", help="list, size and clear the cache of synthetic materials and captures",
        description=DESCRIPTION, formatter_class=argparse.RawDescriptionHelpFormatter,
    )  # fmt: skip
    s.add_argument("--json", action="store_true", help="print one JSON object")
    actions = s.add_subparsers(dest="action", metavar="ACTION",
                               help="list (the default), size or clear")  # fmt: skip
    for name, text in (("list", "the entries with their sizes, least recently used first"),
                       ("size", "the number of entries and their total size")):  # fmt: skip
        a = actions.add_parser(name, help=text, description=text)
        a.add_argument("--json", action="store_true", default=argparse.SUPPRESS,
                       help="print one JSON object")  # fmt: skip
    c = actions.add_parser(
        "clear",
        help="remove every entry, or those matching PATTERN",
        description="Remove every cache entry, or those whose name contains "
        "a PATTERN or matches it as a wildcard (synth-*-600x600-*).",
    )
    c.add_argument(
        "patterns",
        metavar="PATTERN",
        nargs="*",
        help="part of an entry's name, or a wildcard (default: every entry)",
    )
    c.add_argument("--json", action="store_true", default=argparse.SUPPRESS,
                   help="print one JSON object")  # fmt: skip
    s.set_defaults(func=run, action=None, patterns=[])

"""The cache of rendered synthetic materials and captures: where it lives, what it holds, its cap.

:func:`sparsebtf.data.synth.cached` (``synth:CLASS`` inputs, ``sparsebtf demo``, the
benchmarks) and :func:`sparsebtf.data.capture.cached_capture` render a material once into a
dense float32 file here and reopen it afterwards. The folder is ``$SPARSEBTF_CACHE``, else
``~/.cache/sparsebtf``. A file holds H·W·L·V·3 float32 values: 424 MiB for 400×400 texels at
UBO2014's 151 × 151 directions, 952 MiB for 600×600; ``sparsebtf demo`` leaves about 4 GB.

* A write of at least :data:`NOTE_BYTES` is announced before it starts (a warning, one
  ``sparsebtf: note:`` line in the CLI) with its size and folder.
* ``$SPARSEBTF_CACHE_MAX`` (``2GB``, ``500MiB``, ``1.5G``, a number of bytes; ``0`` keeps
  only the newest) caps the folder: after each write the least recently used entries are
  removed until the rest fit, never the one just written nor one this process has opened
  (its readers, or Dask workers given the path, would fail; a note says when that keeps the
  folder over the cap). Reusing an entry marks it used (its modification time).
* ``sparsebtf cache`` lists the entries and their sizes and clears them (all, or by pattern).

Only our own files count as entries (``synth-*.h5``, ``capture-*.h5`` and a capture's
resumable ``capture-*.h5.partial``), so a cache folder pointed at a busy directory loses nothing
else. Files being written (``.NAME…part``) are neither listed nor removed.
"""

from __future__ import annotations

import contextlib
import fnmatch
import os
import re
import time
import warnings
from dataclasses import dataclass
from pathlib import Path

from .._limits import format_bytes
from ..errors import SparseBTFError

__all__ = [
    "CACHE_MAX_VARIABLE",
    "NOTE_BYTES",
    "CacheEntry",
    "announce_write",
    "cache_cap",
    "check_folder",
    "clear",
    "enforce_cap",
    "entries",
    "mark_used",
    "parse_size",
    "resolve_cache_dir",
]

#: Writes of at least this many bytes are announced (a demo material is 424 MiB).
NOTE_BYTES = 64 * 2**20
#: The environment variable that caps the cache.
CACHE_MAX_VARIABLE = "SPARSEBTF_CACHE_MAX"
#: Our entries' names (anything else in the folder is not ours to list or remove).
ENTRY_PATTERNS = ("synth-*.h5", "capture-*.h5", "capture-*.h5.partial")

_UNITS = {"": 1, "b": 1, "k": 2**10, "m": 2**20, "g": 2**30, "t": 2**40,
          "kb": 10**3, "mb": 10**6, "gb": 10**9, "tb": 10**12,
          "kib": 2**10, "mib": 2**20, "gib": 2**30, "tib": 2**40}  # fmt: skip
#: Entries this process has written or reused: never evicted while it runs.
_IN_USE: set[str] = set()
_SIZE_RE = re.compile(r"^\s*(\d+(?:\.\d*)?|\.\d+)\s*([a-z]*)\s*$", re.I)


def resolve_cache_dir(path: str | os.PathLike[str] | None = None) -> Path:
    """The cache folder: ``path``, else ``$SPARSEBTF_CACHE``, else ``~/.cache/sparsebtf``."""
    if path is not None:
        return Path(path)
    env = os.environ.get("SPARSEBTF_CACHE")
    if env:
        return Path(env)
    return Path.home() / ".cache" / "sparsebtf"


@dataclass(frozen=True)
class CacheEntry:
    """One cached file: its path, bytes on disk and when it was last written or reused."""

    path: Path
    bytes: int
    last_used: float

    def as_dict(self) -> dict[str, object]:
        used = time.strftime("%Y-%m-%dT%H:%M:%S", time.localtime(self.last_used))
        return {"name": self.path.name, "path": str(self.path), "bytes": self.bytes,
                "last_used": used}  # fmt: skip


def parse_size(text: str, what: str = CACHE_MAX_VARIABLE) -> int:
    """Bytes from ``2GB`` (10⁹), ``2GiB`` / ``2G`` (2³⁰), ``500MB``, ``1.5T``, ``123`` (bytes)."""
    m = _SIZE_RE.match(text)
    unit = m.group(2).lower() if m else ""
    if m is None or unit not in _UNITS:
        raise SparseBTFError(
            f"{what}={text!r}: expected a size such as 2GB, 500MiB, 1.5G or a number of bytes"
        )
    return int(float(m.group(1)) * _UNITS[unit])


def cache_cap() -> int | None:
    """The cap from ``$SPARSEBTF_CACHE_MAX`` in bytes, None when unset (no cap)."""
    text = os.environ.get(CACHE_MAX_VARIABLE, "").strip()
    return parse_size(text) if text else None


def check_folder(folder: str | os.PathLike[str] | None = None) -> Path:
    """The cache folder (:func:`resolve_cache_dir`); something else than a folder at its path
    (a file) is refused in one line naming it. A folder not made yet is no error: nothing is
    cached yet."""
    d = resolve_cache_dir(folder)
    if d.exists() and not d.is_dir():
        where = ("set $SPARSEBTF_CACHE to a folder (or unset it for ~/.cache/sparsebtf)"
                 if folder is None else "give a folder")  # fmt: skip
        raise SparseBTFError(f"the cache folder {d} is a file, not a folder: {where}")
    return d


def entries(folder: str | os.PathLike[str] | None = None) -> list[CacheEntry]:
    """The cache's entries, least recently used first (ties by name); none while the folder
    is not made yet, a refusal where a file stands in its place (:func:`check_folder`)."""
    d = check_folder(folder)
    found: list[CacheEntry] = []
    with contextlib.suppress(FileNotFoundError):
        for item in os.scandir(d):
            if not _is_entry(item.name) or not item.is_file(follow_symlinks=False):
                continue
            with contextlib.suppress(FileNotFoundError):  # removed meanwhile
                st = item.stat(follow_symlinks=False)
                found.append(CacheEntry(Path(item.path), st.st_size, st.st_mtime))
    return sorted(found, key=lambda e: (e.last_used, e.path.name))


def clear(
    patterns: tuple[str, ...] | list[str] = (), folder: str | os.PathLike[str] | None = None
) -> list[CacheEntry]:
    """Remove the entries whose name matches one of ``patterns`` (shell wildcards; a pattern
    without one matches names containing it), or every entry; the ones removed."""
    removed = []
    for e in entries(folder):
        if patterns and not any(_matches(e.path.name, p) for p in patterns):
            continue
        with contextlib.suppress(FileNotFoundError):
            e.path.unlink()
            removed.append(e)
    return removed


def mark_used(path: str | os.PathLike[str], touch: bool = True) -> None:
    """Note that a cached file is in use by this process (kept from eviction while it runs)
    and, with ``touch``, that it was reused (its mtime: the cap evicts the least recent)."""
    _IN_USE.add(os.path.abspath(path))
    if touch:
        with contextlib.suppress(OSError):  # a read-only, shared cache is used as it is
            os.utime(path)


def announce_write(path: str | os.PathLike[str], nbytes: int) -> None:
    """Warn, before a cache write of at least :data:`NOTE_BYTES`, what it costs and where.

    Also checks ``$SPARSEBTF_CACHE_MAX`` before the work, so a bad value is one line then."""
    cap = cache_cap()
    if nbytes < NOTE_BYTES:
        return
    p = Path(path)
    total = sum(e.bytes for e in entries(p.parent))
    capped = (f"capped at {format_bytes(cap)} by {CACHE_MAX_VARIABLE}" if cap is not None
              else f"set {CACHE_MAX_VARIABLE} (e.g. 2GB) to cap it")  # fmt: skip
    # how to list, clear and cap the cache: once per folder and process (a benchmark caches
    # a dozen materials in a row)
    hint = "" if p.parent in _HINTED else f"; 'sparsebtf cache' lists and clears it, {capped}"
    _HINTED.add(p.parent)
    warnings.warn(
        f"caching {p.name} ({format_bytes(nbytes)}) in {p.parent} (holding "
        f"{format_bytes(total)}){hint}",
        stacklevel=3,
    )


#: the cache folders whose first large-write note this process has given (with the hint)
_HINTED: set[Path] = set()


def enforce_cap(just_written: str | os.PathLike[str]) -> list[CacheEntry]:
    """After a write: remove the least recently used entries until the folder fits
    ``$SPARSEBTF_CACHE_MAX``, never ``just_written``; the ones removed (said in a warning)."""
    cap = cache_cap()
    if cap is None:
        return []
    keep = Path(just_written)
    mark_used(keep, touch=False)
    found = entries(keep.parent)
    total = sum(e.bytes for e in found)
    removed: list[CacheEntry] = []
    kept = 0  # entries this process uses, besides the one just written, kept over the cap
    for e in found:
        if total <= cap:
            break
        if os.path.abspath(e.path) in _IN_USE:
            kept += e.path.name != keep.name
            continue
        with contextlib.suppress(FileNotFoundError):
            e.path.unlink()
            removed.append(e)
        total -= e.bytes
    where = f"the cache {keep.parent} is capped at {format_bytes(cap)} ({CACHE_MAX_VARIABLE})"
    if removed:
        freed = sum(e.bytes for e in removed)
        names = ", ".join(e.path.name for e in removed[:3])
        more = f" and {len(removed) - 3} more" if len(removed) > 3 else ""
        warnings.warn(
            f"{where}: removed {len(removed)} least recently used ({format_bytes(freed)}: "
            f"{names}{more})",
            stacklevel=3,
        )
    if total > cap and kept:
        warnings.warn(
            f"{where} but holds {format_bytes(total)}: {kept} more entries are in use by this "
            "process (a later write removes them once it ends)",
            stacklevel=3,
        )
    return removed


def _is_entry(name: str) -> bool:
    return any(fnmatch.fnmatchcase(name, p) for p in ENTRY_PATTERNS)


def _matches(name: str, pattern: str) -> bool:
    if any(c in pattern for c in "*?["):
        return fnmatch.fnmatchcase(name, pattern)
    return pattern in name

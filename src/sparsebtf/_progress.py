"""Progress bars with ETA for long work (tqdm), silent when asked or when not on a terminal."""

from __future__ import annotations

import os
import sys
from collections.abc import Iterable, Iterator
from typing import TypeVar

from tqdm.auto import tqdm

T = TypeVar("T")


def _enabled(flag: bool | None) -> bool:
    if flag is not None:
        return flag
    if os.environ.get("SPARSEBTF_PROGRESS") in ("0", "1"):
        return os.environ["SPARSEBTF_PROGRESS"] == "1"
    return sys.stderr.isatty()


def progress(
    iterable: Iterable[T], total: int | None = None, desc: str = "", enabled: bool | None = None
) -> Iterator[T]:
    """Wrap ``iterable`` in a progress bar (rate and ETA) on stderr when enabled."""
    if not _enabled(enabled):
        yield from iterable
        return
    yield from tqdm(iterable, total=total, desc=desc, unit="it", dynamic_ncols=True, leave=False)


def bar(total: int, desc: str = "", unit: str = "it", enabled: bool | None = None) -> tqdm:
    """A manual progress bar (``.update(n)``); disabled bars cost nothing."""
    return tqdm(
        total=total,
        desc=desc,
        unit=unit,
        dynamic_ncols=True,
        leave=False,
        disable=not _enabled(enabled),
    )

"""Progress for long work: a bar with ETA (tqdm) on a terminal, a line every ~5 % or 30 s
on a log (stderr not a terminal: nohup, batch jobs, CI), nothing when asked.

``SPARSEBTF_PROGRESS=0`` silences both, ``1`` forces the bar even without a terminal; unset,
stderr decides (a terminal: the bar; anything else: the lines of :class:`LogLines`).
"""

from __future__ import annotations

import os
import sys
import time
from collections.abc import Iterable, Iterator
from typing import Any, TypeVar

from tqdm.auto import tqdm

T = TypeVar("T")

#: A log line at least every this many seconds while work goes on ...
LOG_EVERY_S = 30.0
#: ... and at every this-much of the total done (but not more than once a second).
LOG_STEP = 0.05


def _mode(flag: bool | None) -> str:
    """"bar", "lines" or "off" for a bar whose caller passed ``flag`` (None: decide here)."""
    if flag is False:
        return "off"
    env = os.environ.get("SPARSEBTF_PROGRESS")
    if flag is True or env == "1":
        return "bar"
    if env == "0":
        return "off"
    return "bar" if sys.stderr.isatty() else "lines"


def _duration(seconds: float) -> str:
    """``42s``, ``3m07s``, ``2h05m``."""
    s = round(seconds)
    if s < 60:
        return f"{s}s"
    if s < 3600:
        return f"{s // 60}m{s % 60:02d}s"
    return f"{s // 3600}h{s % 3600 // 60:02d}m"


class LogLines:
    """A progress "bar" for logs: ``update(n)`` like tqdm's, one line per ~5 % or 30 s::

        sparsebtf: encode stone: 45% (720/1600 pt), 2.10 pt/s, elapsed 5m43s, ETA 7m00s

    and a last line with the total time when it closes (only for work that took a second or
    more or already printed a line, so quick steps stay quiet).
    """

    def __init__(self, total: int, desc: str = "", unit: str = "it") -> None:
        self.total, self.desc, self.unit = max(0, int(total)), desc, unit
        self.n = 0
        self._t0 = self._last = time.monotonic()
        self._next_step = LOG_STEP
        self._printed = False
        self._closed = False

    def update(self, n: int = 1) -> None:
        self.n += int(n)
        now = time.monotonic()
        frac = self.n / self.total if self.total else 0.0
        step = frac >= self._next_step and now - self._last >= 1.0
        if step or now - self._last >= LOG_EVERY_S:
            self._line(now)
            while self._next_step <= frac:
                self._next_step += LOG_STEP

    def _line(self, now: float) -> None:
        elapsed = now - self._t0
        rate = self.n / elapsed if elapsed > 0 else 0.0
        what = f"{self.desc}: " if self.desc else ""
        pct = f"{100 * self.n / self.total:.0f}% " if self.total else ""
        eta = ""
        if rate > 0 and self.total > self.n:
            eta = f", ETA {_duration((self.total - self.n) / rate)}"
        print(f"sparsebtf: {what}{pct}({self.n}/{self.total} {self.unit}), {rate:.3g} "
              f"{self.unit}/s, elapsed {_duration(elapsed)}{eta}", file=sys.stderr,
              flush=True)  # fmt: skip
        self._last, self._printed = now, True

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        elapsed = time.monotonic() - self._t0
        if self.n and (self._printed or elapsed >= 1.0):
            what = f"{self.desc}: " if self.desc else ""
            print(f"sparsebtf: {what}done, {self.n} {self.unit} in {_duration(elapsed)}",
                  file=sys.stderr, flush=True)  # fmt: skip

    def __enter__(self) -> LogLines:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()


def progress(
    iterable: Iterable[T], total: int | None = None, desc: str = "", enabled: bool | None = None
) -> Iterator[T]:
    """Wrap ``iterable`` in a progress bar (rate and ETA) on stderr when enabled."""
    mode = _mode(enabled)
    if mode == "off":
        yield from iterable
        return
    if mode == "lines":
        if total is None and hasattr(iterable, "__len__"):
            total = len(iterable)  # type: ignore[arg-type]
        with LogLines(total or 0, desc) as pb:
            for item in iterable:
                yield item
                pb.update(1)
        return
    yield from tqdm(iterable, total=total, desc=desc, unit="it", dynamic_ncols=True, leave=False)


def bar(total: int, desc: str = "", unit: str = "it", enabled: bool | None = None
        ) -> tqdm | LogLines:  # fmt: skip
    """A manual progress bar (``.update(n)``, a context manager); disabled bars cost nothing."""
    mode = _mode(enabled)
    if mode == "lines":
        return LogLines(total, desc, unit)
    return tqdm(
        total=total,
        desc=desc,
        unit=unit,
        dynamic_ncols=True,
        leave=False,
        disable=mode == "off",
    )

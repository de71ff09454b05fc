"""The memory budget: the most one allocation may take when its size comes from a file or a
read request. Every reader checks a size it read from a file against the file's own size and
against this budget *before* allocating, so a damaged header gives an error, not a 32 GiB
``np.empty``. ``SPARSEBTF_MAX_MEMORY_GB`` (default 2, the limit :meth:`BTF.to_array` always
had) raises or lowers it.
"""

from __future__ import annotations

import math
import os

from .errors import SparseBTFError

__all__ = ["ENV", "check_allocation", "format_bytes", "memory_budget"]

ENV = "SPARSEBTF_MAX_MEMORY_GB"
DEFAULT_GB = 2.0


def memory_budget() -> int:
    """The budget in bytes (``$SPARSEBTF_MAX_MEMORY_GB`` GiB, default 2 GiB)."""
    text = os.environ.get(ENV)
    if not text:
        return int(DEFAULT_GB * 2**30)
    try:
        gb = float(text)
    except ValueError:
        gb = math.nan
    if not (math.isfinite(gb) and gb > 0):
        raise SparseBTFError(f"${ENV} must be a positive number of GiB, got {text!r}")
    return int(gb * 2**30)


def format_bytes(n: float) -> str:
    """``1.5 GiB``, ``320 MiB``, ``12 KiB``, ``7 B``."""
    for unit, scale in (("TiB", 2**40), ("GiB", 2**30), ("MiB", 2**20), ("KiB", 2**10)):
        if n >= scale:
            return f"{n / scale:.3g} {unit}"
    return f"{int(n)} B"


def check_allocation(nbytes: int, what: str, exc: type[SparseBTFError] = SparseBTFError) -> None:
    """Raise ``exc`` when ``nbytes`` (for ``what``, e.g. "file.h5: /codes/Y/values") exceeds
    the budget; the message names both sizes and the variable that raises the budget."""
    budget = memory_budget()
    if nbytes > budget:
        raise exc(
            f"{what} needs {format_bytes(nbytes)} of memory, above the budget of "
            f"{format_bytes(budget)} (set ${ENV} to allow more)"
        )

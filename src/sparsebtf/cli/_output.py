"""How every command prints: one JSON object (``--json``) or a two-column table; results
with NaN or infinity are refused (one error line) unless ``--allow-nonfinite`` is given."""

from __future__ import annotations

import json
import math
from collections.abc import Iterator
from typing import Any

import numpy as np

from .._json import json_default
from ..errors import SparseBTFError

__all__ = ["add_allow_nonfinite", "check_finite_result", "print_json", "table"]

#: The one flag, the same in every command that prints numbers.
ALLOW_NONFINITE = "--allow-nonfinite"


def add_allow_nonfinite(parser: Any) -> None:
    """Add ``--allow-nonfinite`` to a command that prints numeric results."""
    parser.add_argument(
        ALLOW_NONFINITE, action="store_true",
        help="print results even when some are NaN or infinite (default: an error, exit 2)",
    )  # fmt: skip


def _numbers(obj: Any, key: str) -> Iterator[tuple[str, float]]:
    """Every number in a nested dict / list / array, with its key path."""
    if isinstance(obj, dict):
        for k, v in obj.items():
            yield from _numbers(v, f"{key}.{k}" if key else str(k))
    elif isinstance(obj, list | tuple):
        for i, v in enumerate(obj):
            yield from _numbers(v, f"{key}[{i}]")
    elif isinstance(obj, np.ndarray) and obj.dtype.kind in "fc":
        bad = ~np.isfinite(obj)
        if bad.any():
            i = tuple(int(x[0]) for x in np.nonzero(bad))
            yield f"{key}{list(i)}", float(obj[i])
    elif isinstance(obj, float | np.floating) and not isinstance(obj, bool):
        yield key, float(obj)


def check_finite_result(
    obj: Any, command: str, allow: bool = False, exact: tuple[str, ...] = ()
) -> None:
    """Refuse a result holding NaN or ±inf (one line naming the first such field), unless
    ``allow`` (the user gave ``--allow-nonfinite``). ``exact`` names fields whose +inf is the
    exact answer (the PSNR of identical images)."""
    if allow:
        return
    bad = [(k, v) for k, v in _numbers(obj, "")
           if not math.isfinite(v) and not (k in exact and v == math.inf)]  # fmt: skip
    if bad:
        key, value = bad[0]
        raise SparseBTFError(
            f"{command}: the result {key} is {value} ({len(bad)} non-finite numbers): the "
            f"decoded values overflow or an input is damaged; {ALLOW_NONFINITE} prints it anyway"
        )


def print_json(obj: Any) -> None:
    """``obj`` as indented JSON on stdout (NumPy values and paths converted)."""
    print(json.dumps(obj, indent=2, sort_keys=True, default=json_default))


def table(rows: list[tuple[str, Any]]) -> str:
    """Aligned ``key  value`` lines."""
    width = max(len(k) for k, _ in rows)
    return "\n".join(f"{k:<{width}}  {v}" for k, v in rows)

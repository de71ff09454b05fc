"""How every command prints: one JSON object (``--json``) or a two-column table."""

from __future__ import annotations

import json
from typing import Any

from .._json import json_default

__all__ = ["print_json", "table"]


def print_json(obj: Any) -> None:
    """``obj`` as indented JSON on stdout (NumPy values and paths converted)."""
    print(json.dumps(obj, indent=2, sort_keys=True, default=json_default))


def table(rows: list[tuple[str, Any]]) -> str:
    """Aligned ``key  value`` lines."""
    width = max(len(k) for k, _ in rows)
    return "\n".join(f"{k:<{width}}  {v}" for k, v in rows)

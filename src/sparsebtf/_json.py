"""JSON of metadata and results holding NumPy values (shared by files, reports and the viewer)."""

from __future__ import annotations

import os
from typing import Any

import numpy as np

__all__ = ["json_default"]


def json_default(obj: Any) -> Any:
    """``default=`` for :func:`json.dumps`: arrays → lists, NumPy scalars → Python numbers,
    sets → sorted lists, paths → strings, anything else → ``str``."""
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, (set, frozenset)):
        return sorted(obj, key=str)
    if isinstance(obj, os.PathLike):
        return os.fspath(obj)
    return str(obj)

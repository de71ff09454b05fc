"""The installed version, below every layer (files record the library that wrote them)."""

from __future__ import annotations

__all__ = ["library_version"]


def library_version() -> str:
    """The installed ``sparsebtf`` version, or ``"unknown"`` when not installed."""
    from importlib import metadata

    try:
        return metadata.version("sparsebtf")
    except metadata.PackageNotFoundError:
        return "unknown"

"""SparseBTF: sparse representation learning for Bidirectional Texture Functions (EGSR 2023)."""

from __future__ import annotations

from importlib import metadata


def library_version() -> str:
    """The installed ``sparsebtf`` version, or ``"unknown"`` when not installed."""
    try:
        return metadata.version("sparsebtf")
    except metadata.PackageNotFoundError:
        return "unknown"

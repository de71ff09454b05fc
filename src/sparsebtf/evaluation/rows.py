"""Queries on a ``bench quality`` results object's rows (shared by the report's modules).

A row is one material coded by one method at one level (``results.json``'s ``rows``); rows
of the methods coded under a storage matching carry ``matching`` (runs before matchings
existed: every row was matched per material).
"""

from __future__ import annotations

from typing import Any

__all__ = ["find", "get", "label", "levels", "matching_of", "materials", "method_order", "rows"]


def rows(result: dict[str, Any], **match: Any) -> list[dict[str, Any]]:
    """Every row whose fields equal ``match`` (a field a row lacks matches nothing but a
    ``None`` wanted value)."""
    return [r for r in result["rows"] if all(r.get(k) == v for k, v in match.items())]


def get(result: dict[str, Any], **match: Any) -> dict[str, Any] | None:
    """The first row matching ``match``, or None."""
    found = rows(result, **match)
    return found[0] if found else None


def materials(result: dict[str, Any], which: str) -> list[str]:
    """The materials of set ``which`` ("test", "table5", "black"), in row order."""
    seen: list[str] = []
    for r in result["rows"]:
        if r["set"] == which and r["material"] not in seen:
            seen.append(r["material"])
    return seen


def levels(result: dict[str, Any]) -> list[int]:
    """The run's storage levels."""
    return [int(v) for v in result["config"]["levels"]]


def matching_of(row: dict[str, Any]) -> str:
    """A row's storage matching (rows before matchings existed: per material)."""
    return row.get("matching") or "per_material"


def method_order(result: dict[str, Any], which: str | None = None) -> list[str]:
    """The methods with rows (in set ``which``, or any), in row order: the reference first."""
    seen: list[str] = []
    for r in result["rows"]:
        if (which is None or r["set"] == which) and r["method"] not in seen:
            seen.append(r["method"])
    return seen


def find(
    result: dict[str, Any], matching: str | None = None, factor: float | None = None,
    **match: Any,
) -> dict[str, Any] | None:  # fmt: skip
    """The first row matching ``match`` coded under ``matching`` at budget ``factor`` (None:
    any). Rows without a ``matching`` (the reference's, and every row of runs before
    matchings) stand under every matching."""
    for r in rows(result, **match):
        if matching is not None and r.get("matching", matching) != matching:
            continue
        if factor is not None and r.get("budget_factor", 1) != factor:
            continue
        return r
    return None


def label(result: dict[str, Any], method: str) -> str:
    """How tables name ``method`` (its label in the run, else its key)."""
    return result.get("methods", {}).get(method, method)

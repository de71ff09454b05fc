"""Checkpoints of an encode: the results of its finished point ranges, so that an interrupted or
killed run continues where it stopped (``sparsebtf encode --resume``).

A checkpoint folder holds one ``points_B_LO_HI.npz`` per finished range ``[LO, HI)`` of input
``B`` (0-based, in the order given), written atomically as the range's result arrives, with:

* ``key``: a JSON fingerprint of everything that decides the range's codes (:func:`range_key`):
  the input (name, shape, directions, and its statistics as a content fingerprint: mean, σ,
  bound and log offset of every angular image), the model's content hash, the plan (τ, ε, rate
  targets, dtype, the dictionary rule: exhaustive or screened with its candidates...), the
  standardisation, the batch size and the range layout;
* the result's arrays (any nesting of lists, dicts, :class:`SparseCodes` and arrays, laid out
  by a JSON ``tree``), and ``sha256`` over all of them
  (:func:`~sparsebtf.checkpoints.checkpoint_digest`, as training's checkpoints).

A resumed run checks every file first (all but the statistics before the statistics pass,
then those) and reads each range back instead of coding it when its turn comes (one range in
memory at a time); ranges start on batch boundaries, so the coded file equals an uninterrupted
run's. A file that does not match this run is one
line naming what differs; a damaged one, one line naming the file.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import re
from pathlib import Path
from typing import Any

import numpy as np

from .._atomic import remove_stale_parts
from ..checkpoints import check_key, read_checkpoint, write_checkpoint
from ..errors import BTFInputError, FileFormatError
from ..learning.coding import SparseCodes

__all__ = ["EncodeCheckpoint", "range_key", "range_layout"]

#: The entries of a key that come from the statistics pass.
MEASURED = ("statistics", "std_mode", "log_offset")

_NAME = re.compile(r"^points_(\d+)_(\d+)_(\d+)\.npz$")
_CODES = tuple(f.name for f in dataclasses.fields(SparseCodes) if f.name != "mode_sizes")


def range_layout(n_points: int, range_points: int) -> list[tuple[int, int]]:
    """``[lo, hi)`` ranges of ``range_points`` points (the last shorter) covering ``n_points``:
    the same whatever runs them, so a run can resume in process or on any cluster."""
    return [(lo, min(lo + range_points, n_points)) for lo in range(0, n_points, range_points)]


def _digest(*arrays: Any) -> str:
    h = hashlib.sha256()
    for a in arrays:
        if a is None:
            h.update(b"none|")
            continue
        a = np.ascontiguousarray(a)
        h.update(f"{a.dtype.str}|{a.shape}|".encode())
        h.update(a.tobytes())
    return h.hexdigest()[:16]


def range_key(header: Any, model: Any, plan: Any, stats: Any, batch_size: int,
              ranges: list[tuple[int, int]]) -> dict[str, Any]:  # fmt: skip
    """The fingerprint of one input's ranges (JSON-able; see the module docstring); without
    ``stats`` (before the statistics pass) it leaves out :data:`MEASURED`."""
    plan_params = dataclasses.asdict(plan) if dataclasses.is_dataclass(plan) else repr(plan)
    measured = {} if stats is None else {
        "statistics": _digest(stats.mean, stats.std, stats.bound, np.float64(stats.log_offset)),
        "std_mode": stats.mode,
        "log_offset": float(stats.log_offset),
    }  # fmt: skip
    return {
        "input": header.name,
        "shape": list(header.shape),
        "directions": _digest(header.lights.xyz, header.views.xyz),
        **measured,
        "model": model.content_hash,
        "plan": type(plan).__name__,
        "dictionary_rule": _rule(plan),
        "plan_parameters": json.loads(json.dumps(plan_params, default=str)),
        "batch_size": batch_size,
        "ranges": len(ranges),
        "range_points": ranges[0][1] - ranges[0][0] if ranges else 0,
    }


def _rule(plan: Any) -> str:
    """How the plan chooses each point's dictionary, named in a refusal: "exhaustive" or
    "screened, N candidates" (also in the plan's parameters, but spelt out here so that a
    screened checkpoint is never resumed by an exhaustive run unnoticed)."""
    c = getattr(plan, "candidates", None)
    return "exhaustive" if c is None else f"screened, {c} candidates"


def _flatten(obj: Any, arrays: dict[str, np.ndarray]) -> Any:
    """A JSON tree of ``obj`` whose arrays go to ``arrays`` (named a0, a1, ...)."""
    if isinstance(obj, np.ndarray):
        name = f"a{len(arrays)}"
        arrays[name] = obj
        return {"array": name}
    if isinstance(obj, SparseCodes):
        return {"codes": list(obj.mode_sizes),
                "fields": {f: _flatten(getattr(obj, f), arrays) for f in _CODES}}  # fmt: skip
    if isinstance(obj, dict):
        return {"dict": {str(k): _flatten(v, arrays) for k, v in obj.items()}}
    if isinstance(obj, list | tuple):
        return {"list": [_flatten(v, arrays) for v in obj]}
    if isinstance(obj, np.generic):
        return {"value": obj.item()}
    if obj is None or isinstance(obj, bool | int | float | str):
        return {"value": obj}
    raise TypeError(f"cannot checkpoint a {type(obj).__name__}")


def _unflatten(tree: Any, arrays: dict[str, np.ndarray]) -> Any:
    if "array" in tree:
        return arrays[tree["array"]]
    if "codes" in tree:
        fields = {f: _unflatten(v, arrays) for f, v in tree["fields"].items()}
        return SparseCodes(tuple(tree["codes"]), **fields)
    if "dict" in tree:
        return {k: _unflatten(v, arrays) for k, v in tree["dict"].items()}
    if "list" in tree:
        return [_unflatten(v, arrays) for v in tree["list"]]
    return tree["value"]


class EncodeCheckpoint:
    """The checkpoint folder of one encode (created on the first save)."""

    def __init__(self, folder: str | os.PathLike[str]) -> None:
        self.folder = Path(folder)

    def path(self, b: int, lo: int, hi: int) -> Path:
        return self.folder / f"points_{b}_{lo}_{hi}.npz"

    def files(self) -> list[Path]:
        """The range files in the folder, in name order."""
        if not self.folder.is_dir():
            return []
        return sorted(p for p in self.folder.iterdir() if _NAME.match(p.name))

    def save(self, b: int, lo: int, hi: int, key: dict[str, Any], part: Any) -> None:
        """Write range ``[lo, hi)`` of input ``b`` (atomically: a kill leaves no half file)."""
        arrays: dict[str, np.ndarray] = {}
        tree = _flatten(part, arrays)
        arrays["tree"] = np.asarray(json.dumps(tree))
        arrays["key"] = np.asarray(json.dumps(key, sort_keys=True))
        self.folder.mkdir(parents=True, exist_ok=True)
        write_checkpoint(self.path(b, lo, hi), arrays)

    def scan(
        self, keys: list[dict[str, Any]], ranges: list[list[tuple[int, int]]],
        skip: tuple[str, ...] = (),
    ) -> list[dict[tuple[int, int], dict[str, Any]]]:  # fmt: skip
        """Per input, its finished ranges and their keys, ``{(lo, hi): key}``, every file read
        and verified (its result is read again, by :meth:`read`, when it is needed: memory
        holds one range at a time, not a whole resumed job).

        Every file must belong to this run: its input ``b`` among ``keys``, its key equal to
        ``keys[b]`` (but for the entries in ``skip``, checked later by :meth:`check`), its
        range in ``ranges[b]``; otherwise one line says what differs.
        """
        done: list[dict[tuple[int, int], dict[str, Any]]] = [{} for _ in keys]
        for path in self.files():
            b, lo, hi = (int(g) for g in _NAME.match(path.name).groups())  # type: ignore[union-attr]
            if b >= len(keys):
                raise BTFInputError(
                    f"checkpoint {path} is for input {b + 1}, but this run has {len(keys)} "
                    "input(s); resume with the same inputs, or delete the folder to start over"
                )
            found, _ = self._read(path)
            want = {k: v for k, v in keys[b].items() if k not in skip}
            check_key(path, {k: v for k, v in found.items() if k not in skip}, want,
                       "inputs or encoding parameters")  # fmt: skip
            if (lo, hi) not in ranges[b]:
                raise BTFInputError(
                    f"checkpoint {path}: points [{lo}, {hi}) are not a range of this run's "
                    f"layout ({len(ranges[b])} ranges); delete the folder to start over"
                )
            done[b][(lo, hi)] = found
        return done

    def check(self, done: list[dict[tuple[int, int], dict[str, Any]]],
              keys: list[dict[str, Any]]) -> list[set[tuple[int, int]]]:  # fmt: skip
        """The ranges found by :meth:`scan` once the entries it skipped are known: every key
        must now equal ``keys[b]`` in full (one line otherwise)."""
        for b, ranges in enumerate(done):
            for (lo, hi), found in ranges.items():
                check_key(self.path(b, lo, hi), found, keys[b], "inputs or encoding parameters")
        return [set(ranges) for ranges in done]

    def read(self, b: int, lo: int, hi: int, key: dict[str, Any]) -> Any:
        """The result saved for range ``[lo, hi)`` of input ``b`` (verified again: SHA-256,
        and ``key``, in case the file changed since :meth:`scan`)."""
        path = self.path(b, lo, hi)
        found, part = self._read(path)
        check_key(path, found, key, "inputs or encoding parameters")
        return part

    def _read(self, path: Path) -> tuple[dict[str, Any], Any]:
        """(key, result) of one file, or one line naming it."""
        arrays = read_checkpoint(path, required=("key", "tree"))
        try:
            found = json.loads(str(arrays.pop("key")))
            tree = json.loads(str(arrays.pop("tree")))
            return found, _unflatten(tree, arrays)
        except (ValueError, KeyError, TypeError, AttributeError) as e:
            raise FileFormatError(
                f"checkpoint {path}: not an encode checkpoint ({type(e).__name__}: {e}); "
                "delete it to start over"
            ) from None

    def remove(self) -> None:
        """Delete the range files (and temporaries left by a killed writer), and the folder
        if nothing else is in it."""
        for p in self.files():
            p.unlink(missing_ok=True)
        remove_stale_parts(self.folder / "points")
        try:
            self.folder.rmdir()
        except OSError:
            pass

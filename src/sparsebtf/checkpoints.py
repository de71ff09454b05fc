"""Checkpoint files: named arrays in one ``.npz`` with the SHA-256 of their content.

Training (:mod:`sparsebtf.learning.ensemble`) and encoding (:mod:`sparsebtf.codec.checkpoint`)
save their progress this way, so that an interrupted run resumes where it stopped:
:func:`write_checkpoint` writes atomically (a kill leaves no half file) with ``sha256`` =
:func:`checkpoint_digest` of the arrays; :func:`read_checkpoint` verifies it, so a damaged file
is one line naming it rather than a wrong resume; :func:`check_key` compares the fingerprint
a checkpoint was made with to this run's.
"""

from __future__ import annotations

import hashlib
import json
import os
import zipfile
from typing import Any

import numpy as np

from ._atomic import atomic_output
from .errors import BTFInputError, FileFormatError

__all__ = ["check_key", "checkpoint_digest", "read_checkpoint", "write_checkpoint"]


def checkpoint_digest(arrays: dict[str, np.ndarray]) -> str:
    """SHA-256 over a checkpoint's arrays: for each name in sorted order, the name, dtype,
    shape and C-order bytes."""
    h = hashlib.sha256()
    for name in sorted(arrays):
        a = np.ascontiguousarray(arrays[name])
        h.update(f"{name}|{a.dtype.str}|{a.shape}|".encode())
        h.update(a.tobytes())
    return h.hexdigest()


#: What ``np.load`` raises on a damaged ``.npz`` (truncated, flipped bits: bad CRC, bad zip).
_NPZ_ERRORS = (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile, zipfile.LargeZipFile,
               RuntimeError, TypeError, IndexError, UnicodeDecodeError)  # fmt: skip


def write_checkpoint(path: str | os.PathLike[str], arrays: dict[str, np.ndarray]) -> None:
    """Write ``arrays`` and their ``sha256`` (:func:`checkpoint_digest`) to ``path`` (``.npz``),
    atomically."""
    with atomic_output(path) as tmp, open(tmp, "wb") as f:
        np.savez(f, sha256=np.asarray(checkpoint_digest(arrays)), **arrays)


def read_checkpoint(
    path: str | os.PathLike[str], required: tuple[str, ...]
) -> dict[str, np.ndarray]:
    """The arrays of a checkpoint, verified against the SHA-256 it stores; ``required``: the
    names it must hold besides ``sha256``.

    A damaged, truncated or foreign file is one :class:`FileFormatError` line naming it."""
    try:
        with np.load(path, allow_pickle=False) as ck:
            arrays = {name: ck[name] for name in ck.files}
    except _NPZ_ERRORS as e:
        raise FileFormatError(
            f"checkpoint {path} is damaged or not a checkpoint ({type(e).__name__}: "
            f"{str(e)[:120]}); delete it to start over"
        ) from None
    stored = str(arrays.pop("sha256", ""))
    missing = [k for k in required if k not in arrays]
    if not stored or missing:
        raise FileFormatError(
            f"checkpoint {path}: no {'sha256' if not stored else ', '.join(missing)}: written by "
            "an older version or not a checkpoint; delete it to start over"
        )
    found = checkpoint_digest(arrays)
    if found != stored:
        raise FileFormatError(
            f"checkpoint {path} is damaged: its arrays hash to {found[:12]}…, the file records "
            f"{stored[:12]}…; delete it to start over"
        )
    return arrays


def check_key(path: Any, found: dict[str, Any], want: dict[str, Any],
               what: str = "training parameters or data") -> None:  # fmt: skip
    """One line naming what differs between a checkpoint and this run."""
    diff = [k for k in sorted(set(found) | set(want)) if found.get(k) != want.get(k)]
    if not diff:
        return
    shown = ", ".join(
        f"{k}: {_short(found.get(k))} in the checkpoint, {_short(want.get(k))} now" for k in diff
    )
    raise BTFInputError(
        f"checkpoint {path} was made with other {what} ({shown}); "
        "delete it or choose another checkpoint path"
    )


def _short(v: Any) -> str:
    text = json.dumps(v)
    return text if len(text) <= 40 else text[:37] + "..."

"""Checks on measured values before they enter the pipeline."""

from __future__ import annotations

import warnings

import numpy as np

from ..errors import BTFInputError

AXES = ("row", "col", "light", "view", "channel")


def check_finite(block: np.ndarray, where: str, offset: tuple[int, ...] = ()) -> None:
    """Raise :class:`BTFInputError` with the count and first location of NaN/Inf values.

    ``offset`` is added to the block's indices so the location refers to the whole BTF.
    """
    bad = ~np.isfinite(block)
    if not bad.any():
        return
    first = [int(x[0]) for x in np.nonzero(bad)]
    off = list(offset) + [0] * (len(first) - len(offset))
    loc = ", ".join(
        f"{AXES[i] if i < len(AXES) else i} {first[i] + off[i]}" for i in range(len(first))
    )
    raise BTFInputError(f"{where}: {int(bad.sum())} NaN/Inf values; first at {loc}")


def clamp_negative(block: np.ndarray, where: str) -> np.ndarray:
    """Clamp negative values to 0 with a warning that gives their count.

    Measured BTFs carry small negative noise; the log transform needs x + 1e-5 > 0.
    """
    neg = block < 0
    n = int(neg.sum())
    if n:
        warnings.warn(f"{where}: clamped {n} negative values to 0", stacklevel=3)
        block = np.where(neg, 0, block).astype(block.dtype, copy=False)
    return block

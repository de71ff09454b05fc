"""Checks on measured values before they enter the pipeline."""

from __future__ import annotations

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

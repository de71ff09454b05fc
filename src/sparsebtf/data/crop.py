"""A spatial window of another BTF (``--crop R0:R1,C0:C1``), read lazily."""

from __future__ import annotations

import numpy as np

from ..errors import BTFInputError
from .btf import BTF, Index, as_index


class CroppedBTF(BTF):
    """Rows ``rows`` and columns ``cols`` (step 1) of ``base``; nothing is copied."""

    def __init__(self, base: BTF, rows: slice, cols: slice) -> None:
        r0, r1 = crop_window(rows, base.height, "rows", base.label)
        c0, c1 = crop_window(cols, base.width, "cols", base.label)
        super().__init__(
            r1 - r0, c1 - c0, base.lights, base.views, base.name,
            {**base.attrs, "crop": [r0, r1, c0, c1]},
        )  # fmt: skip
        self.base = base
        self.source = base.source
        self._r0, self._c0 = r0, c0
        hint_rows, hint_views = base.block_hint
        self.block_hint = (min(hint_rows, self.height), hint_views)
        self.serial_reads = base.serial_reads

    def read(self, rows: Index, cols: Index, lights: Index, views: Index) -> np.ndarray:
        r = as_index(rows, self.height, "row") + self._r0
        c = as_index(cols, self.width, "col") + self._c0
        return self.base.read(r, c, lights, views)


def crop_window(window: slice, n: int, axis: str, name: str) -> tuple[int, int]:
    """[start, stop) of a crop window, which must lie inside [0, n): no clipping, no negative
    (count-from-the-end) indices, no steps."""
    start = 0 if window.start is None else int(window.start)
    stop = n if window.stop is None else int(window.stop)
    if (window.step or 1) != 1 or not 0 <= start < stop <= n:
        raise BTFInputError(
            f"{name}: crop {axis} {start}:{stop} must satisfy 0 <= start < stop <= {n} (the "
            f"BTF has {n} {axis}) with step 1"
        )
    return start, stop

"""A spatial window of another BTF (``--crop R0:R1,C0:C1``), read lazily."""

from __future__ import annotations

import numpy as np

from ..errors import BTFInputError
from .btf import BTF, Index, as_index


class CroppedBTF(BTF):
    """Rows ``rows`` and columns ``cols`` (step 1) of ``base``; nothing is copied."""

    def __init__(self, base: BTF, rows: slice, cols: slice) -> None:
        r = np.arange(base.height)[rows]
        c = np.arange(base.width)[cols]
        if r.size == 0 or c.size == 0 or (rows.step or 1) != 1 or (cols.step or 1) != 1:
            raise BTFInputError(
                f"{base.name}: crop rows {rows.start}:{rows.stop}, cols {cols.start}:{cols.stop} "
                f"is empty or strided inside {base.height}x{base.width}"
            )
        super().__init__(
            r.size,
            c.size,
            base.lights,
            base.views,
            base.name,
            {**base.attrs, "crop": [int(r[0]), int(r[-1]) + 1, int(c[0]), int(c[-1]) + 1]},
        )
        self.base = base
        self._r0, self._c0 = int(r[0]), int(c[0])

    def read(self, rows: Index, cols: Index, lights: Index, views: Index) -> np.ndarray:
        r = as_index(rows, self.height, "row") + self._r0
        c = as_index(cols, self.width, "col") + self._c0
        return self.base.read(r, c, lights, views)

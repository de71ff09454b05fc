"""Bilinear lookups into periodic (wrap-around) texel maps, vectorised over all query points.

The material tiles the plane, so a parallax or shadow ray that leaves the tile re-enters on
the opposite side; texel centres sit at integer (row, col).
"""

from __future__ import annotations

import numpy as np

__all__ = ["bilinear_wrap"]


def bilinear_wrap(maps: np.ndarray, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """Sample ``maps`` (H, W) or (H, W, C) at fractional texel positions, wrapping around.

    ``rows`` and ``cols`` have any common shape S; the result has shape S (2D maps) or
    S + (C,) with the dtype of ``maps``.
    """
    h, w = maps.shape[:2]
    flat = maps.reshape(h * w, -1)
    r = np.asarray(rows, dtype=np.float64)
    c = np.asarray(cols, dtype=np.float64)
    r0f = np.floor(r)
    c0f = np.floor(c)
    fr = (r - r0f).astype(maps.dtype)[..., None]
    fc = (c - c0f).astype(maps.dtype)[..., None]
    r0 = np.mod(r0f.astype(np.int64), h)
    c0 = np.mod(c0f.astype(np.int64), w)
    r1 = np.where(r0 + 1 == h, 0, r0 + 1)
    c1 = np.where(c0 + 1 == w, 0, c0 + 1)
    top = flat[r0 * w + c0] * (1 - fc) + flat[r0 * w + c1] * fc
    bot = flat[r1 * w + c0] * (1 - fc) + flat[r1 * w + c1] * fc
    out = top * (1 - fr) + bot * fr
    return out[..., 0] if maps.ndim == 2 else out

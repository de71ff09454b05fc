"""Locations of kept coefficients as stored in coded files: a data point's multi-index
(l1, …, lN) packed into w little-endian bytes of its column-major linear index
(:func:`~sparsebtf.learning.cost.location_width` bytes: 3 for the release's 10×10×151×151
points), the release's storage order (MATLAB's ``sub2ind``)."""

from __future__ import annotations

import numpy as np

from ..errors import BTFInputError
from ..learning.cost import location_width

__all__ = ["pack_locations", "unpack_locations"]


def pack_locations(locations: np.ndarray, mode_sizes: tuple[int, ...] | list[int]) -> np.ndarray:
    """Pack (NNZ, N) multi-indices into (NNZ, w) uint8, w = :func:`location_width`.

    The packed value is the column-major linear index ``l1 + m1·l2 + m1·m2·l3 + …`` (the
    release's storage order, MATLAB's ``sub2ind``), written as w little-endian bytes.
    """
    sizes = tuple(int(m) for m in mode_sizes)
    loc = np.asarray(locations)
    if loc.ndim != 2 or loc.shape[1] != len(sizes):
        raise BTFInputError(f"locations must have shape (NNZ, {len(sizes)}), got {loc.shape}")
    width = location_width(sizes)
    if loc.shape[0] == 0:
        return np.zeros((0, width), dtype=np.uint8)
    loc = loc.astype(np.int64, copy=False)
    bad = (loc < 0) | (loc >= np.array(sizes, dtype=np.int64))
    if bad.any():
        row, col = (int(x[0]) for x in np.nonzero(bad))
        raise BTFInputError(
            f"location {row} has index {int(loc[row, col])} on mode {col + 1}, outside "
            f"[0, {sizes[col]})"
        )
    strides = np.cumprod((1, *sizes[:-1]), dtype=np.int64)
    linear = (loc @ strides).astype("<u4")
    return np.ascontiguousarray(linear.view(np.uint8).reshape(-1, 4)[:, :width])


def unpack_locations(packed: np.ndarray, mode_sizes: tuple[int, ...] | list[int]) -> np.ndarray:
    """Inverse of :func:`pack_locations`: (NNZ, w) uint8 → (NNZ, N) int32 multi-indices."""
    sizes = tuple(int(m) for m in mode_sizes)
    b = np.asarray(packed)
    width = location_width(sizes)
    if b.ndim != 2 or b.shape[1] != width or b.dtype != np.uint8:
        raise BTFInputError(
            f"packed locations for modes {sizes} must be (NNZ, {width}) uint8, got "
            f"{b.shape} {b.dtype}"
        )
    full = np.zeros((b.shape[0], 4), dtype=np.uint8)
    full[:, :width] = b
    linear = full.view("<u4").reshape(-1).astype(np.int64)
    total = int(np.prod(sizes, dtype=np.int64))
    if linear.size and int(linear.max()) >= total:
        i = int(np.argmax(linear >= total))
        raise BTFInputError(
            f"packed location {i} decodes to linear index {int(linear[i])}, outside the "
            f"{total} entries of a data point"
        )
    idx = np.unravel_index(linear, sizes, order="F")
    return np.stack(idx, axis=1).astype(np.int32) if sizes else np.zeros((b.shape[0], 0), np.int32)

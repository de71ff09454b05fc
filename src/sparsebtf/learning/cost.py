"""The storage cost of sparse codes: the Table 4 byte formula, written once.

Per channel (the release's ``btf4Dcomp``; ``training-algorithm.md`` §7)::

    bytes = 2·NNZ            binary16 values                       (VALUE_BYTES)
          + w·NNZ            locations: a w-byte linear index, w = location_width(m) (3 for
                             UBO2014's 2,280,100-entry data points, 4 above 2^24 entries)
          + 2·K·Σ m_n²       the channel's K dictionaries in binary16 (DICTIONARY_ENTRY_BYTES)
          + P + P            membership m and count z, one byte per point each (POINT_BYTES)

Storage accounting (:mod:`sparsebtf.storage.accounting`), rate control
(:mod:`sparsebtf.learning.rate_control`, :mod:`sparsebtf.codec.rate`) and the benchmark's
storage levels (:mod:`sparsebtf.evaluation.benchmark_set`) all count with these functions.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from ..errors import BTFInputError

__all__ = [
    "DICTIONARY_ENTRY_BYTES",
    "POINT_BYTES",
    "RAW_VALUE_BYTES",
    "VALUE_BYTES",
    "channel_storage",
    "coefficient_budget",
    "coefficient_bytes",
    "location_width",
    "material_bytes",
    "raw_bytes",
]

#: A coefficient value: binary16.
VALUE_BYTES = 2
#: A dictionary entry: binary16 (the release's ``.bin``; Table 4).
DICTIONARY_ENTRY_BYTES = 2
#: Per data point and channel: one membership byte (m) and one count byte (z).
POINT_BYTES = 2
#: The uncompressed BTF Table 4 compares against: binary16 RGB values.
RAW_VALUE_BYTES = 2


def raw_bytes(n_values: int) -> int:
    """Bytes of the uncompressed BTF (H·W·L·V·3 values in binary16), Table 4's "Full BTF"."""
    return RAW_VALUE_BYTES * int(n_values)


def location_width(mode_sizes: Sequence[int]) -> int:
    """Bytes per packed location: 3 when ∏ m_n <= 2^24 (Table 4's 3 B), else 4."""
    total = int(np.prod([int(m) for m in mode_sizes], dtype=object))
    if total <= 0:
        raise BTFInputError(f"mode sizes must be positive, got {tuple(mode_sizes)}")
    if total <= 1 << 24:
        return 3
    if total <= 1 << 32:
        return 4
    raise BTFInputError(
        f"data points of {total} entries (modes {tuple(mode_sizes)}) exceed the 32-bit "
        f"location index of this format"
    )


def coefficient_bytes(location_bytes: int = 3) -> int:
    """Bytes of one kept coefficient: its value and its packed location."""
    return VALUE_BYTES + int(location_bytes)


def material_bytes(nnz: int, n_points: int, n_channels: int, location_bytes: int = 3) -> int:
    """Per-material bytes of Table 4 (dictionaries excluded): values, locations, m and z."""
    return coefficient_bytes(location_bytes) * int(nnz) + POINT_BYTES * int(n_points) * int(
        n_channels
    )


def coefficient_budget(
    target_bytes: float, n_points: int, n_channels: int, location_bytes: int = 3
) -> int:
    """Coefficients that ``target_bytes`` per material pays for: the inverse of
    :func:`material_bytes` (rounded down)."""
    spare = target_bytes - POINT_BYTES * int(n_points) * int(n_channels)
    return int(spare // coefficient_bytes(location_bytes))


def channel_storage(
    nnz: int, n_points: int, n_dictionaries: int, mode_sizes: Sequence[int]
) -> dict[str, Any]:
    """Bytes of one channel by the Table 4 formula, term by term."""
    sizes = tuple(int(m) for m in mode_sizes)
    loc_w = location_width(sizes)
    dict_entries = int(n_dictionaries) * sum(m * m for m in sizes)
    out = {
        "nnz": int(nnz),
        "n_points": int(n_points),
        "n_dictionaries": int(n_dictionaries),
        "mode_sizes": sizes,
        "dictionary_entries": dict_entries,
        "location_bytes_per_coefficient": loc_w,
        "bytes_values": VALUE_BYTES * int(nnz),
        "bytes_locations": loc_w * int(nnz),
        "bytes_dictionaries": DICTIONARY_ENTRY_BYTES * dict_entries,
        "bytes_membership": POINT_BYTES // 2 * int(n_points),
        "bytes_counts": POINT_BYTES // 2 * int(n_points),
        "mean_coefficients_per_point": float(nnz) / n_points if n_points else 0.0,
    }
    out["bytes_coefficients"] = out["bytes_values"] + out["bytes_locations"]
    out["bytes_total"] = material_bytes(nnz, n_points, 1, loc_w) + out["bytes_dictionaries"]
    return out

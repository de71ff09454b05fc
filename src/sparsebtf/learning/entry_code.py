"""The compact code of the highlight store's entries (issue 46): where a store's bytes go at
high rates, the entries — nodes, and their corrections — are what more bytes buy, so they are
coded at the bytes they need rather than at a coefficient's.

* **Corrections** in OCP FP8 E5M2, one byte a channel: a binary16 with its low mantissa byte
  dropped (rounded to nearest, ties to even). Two mantissa bits keep a correction within
  12.5 % (the squared error it removes, within 1.6 %); the exponent keeps binary16's range,
  so no scale is stored. A decoder widens the byte back to the binary16 ``byte << 8``.
* **Nodes** as the gaps between the store's sorted global keys ``point · N + key`` (N = p²·L·V
  nodes a point, ``key`` as :func:`~sparsebtf.learning.highlights.node_keys`), Golomb–Rice
  coded with one parameter k for the material: gap d = key_j − key_{j−1} − 1 (the first: its
  key) is ``d >> k`` in unary (that many 1 bits, then a 0) and ``d mod 2^k`` in k bits. The
  unary parts and the remainders are kept as two bit streams so that either decodes with
  vector operations (the zeros of the first delimit the entries; the second is k bits each).
  The point counts follow from the keys, so none is stored.

* **Tinted corrections**: one E5M2 scale an entry along its point's tint t (three binary16,
  :data:`TINT_BYTES` a point), c = s·t. A metal's highlight has the metal's colour, so the
  residuals of a point's highlight nodes nearly share one direction in RGB (the tint is the
  principal one, :func:`tint`) and one byte carries what three did.

Bytes of a store of n entries (:func:`compact_bytes`): ⌈U/8⌉ + ⌈n·k/8⌉ + 3n +
:data:`HEADER_BYTES`, U = Σ_j (d_j >> k) + n; tinted, n instead of 3n and 6 bytes a point. At
UBO2014 size that is 4.3–5.2 bytes an entry (a gap of 400–60,000 nodes; 2.3–3.2 tinted)
against 9 for a binary16 entry with a 3-byte location.
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "HEADER_BYTES",
    "MIN_ENTRY_BYTES",
    "TINT_BYTES",
    "compact_bytes",
    "from_e5m2",
    "on_e5m2_grid",
    "pack_keys",
    "quantise",
    "rice_parameter",
    "tint",
    "tint_scales",
    "tinted",
    "to_e5m2",
    "unpack_keys",
]

#: The entry count (uint32) and the Rice parameter (uint8).
HEADER_BYTES = 5
#: The fewest bytes an entry can cost: one E5M2 scale of a tinted store (its gap's bits come
#: on top; three E5M2 values in an untinted one).
MIN_ENTRY_BYTES = 1
#: Bytes of a point's tint: three binary16 values.
TINT_BYTES = 6
_E5M2_MAX = 0x7B  # the largest finite magnitude byte (57,344)


def to_e5m2(x: np.ndarray) -> np.ndarray:
    """Values ``x`` (any float dtype) as E5M2 bytes: (same shape) uint8, through binary16,
    rounded to nearest even; magnitudes past E5M2's largest finite value saturate to it."""
    big = float(np.finfo(np.float16).max)
    h = np.clip(x, -big, big).astype(np.float16).view(np.uint16).astype(np.uint32)
    sign, mag = h & 0x8000, h & 0x7FFF
    # round the low byte away: + 0x7F, + 1 more when the kept byte is odd (ties to even)
    mag = (mag + 0x7F + ((mag >> 8) & 1)) >> 8
    mag = np.minimum(mag, _E5M2_MAX)
    return ((sign >> 8) | mag).astype(np.uint8)


def from_e5m2(b: np.ndarray) -> np.ndarray:
    """E5M2 bytes ``b`` as binary16 (exact): ``b << 8`` read as a half float."""
    return (np.asarray(b, dtype=np.uint8).astype(np.uint16) << 8).view(np.float16)


def quantise(x: np.ndarray) -> np.ndarray:
    """``x`` on the E5M2 grid, as float16 (what a compact store keeps of a correction)."""
    return from_e5m2(to_e5m2(x))


def on_e5m2_grid(x: np.ndarray) -> bool:
    """Whether every value of the float16 array ``x`` is an E5M2 value (the compact code
    keeps it exactly): its low byte is zero and it is finite."""
    h = np.asarray(x, dtype=np.float16)
    return bool(np.all((h.view(np.uint16) & 0xFF) == 0) and np.all(np.isfinite(h)))


def tint(r: np.ndarray) -> np.ndarray:
    """The tint of residuals ``r`` (n, 3): the principal direction of their RGB scatter rᵀr
    (the line through 0 that leaves the least squared error), scaled so its largest
    component is 1 and its sum is ≥ 0, as (3,) float16; (1, 1, 1) where ``r`` is all zero."""
    r = np.asarray(r, dtype=np.float64).reshape(-1, 3)
    scatter = r.T @ r
    if not np.any(scatter):
        return np.ones(3, dtype=np.float16)
    t = np.linalg.eigh(scatter)[1][:, -1]
    t = t / t[np.argmax(np.abs(t))]
    return (t if t.sum() >= 0 else -t).astype(np.float16)


def tint_scales(r: np.ndarray, t: np.ndarray) -> np.ndarray:
    """The E5M2 scales (n,) float16 of residuals ``r`` (n, 3) along the tint ``t`` (3,):
    ``quantise(r·t / t·t)``, the nearest multiple of t on the grid (within its rounding)."""
    t64 = np.asarray(t, dtype=np.float64)
    return quantise(np.asarray(r, dtype=np.float64).reshape(-1, 3) @ t64 / (t64 @ t64))


def tinted(scales: np.ndarray, tints: np.ndarray) -> np.ndarray:
    """The corrections of a tinted store: ``scales`` (n,) times each entry's tint ``tints``
    (n, 3), in float32, rounded to (n, 3) float16 — what every decoder reads."""
    s = np.asarray(scales, dtype=np.float16).astype(np.float32)
    return (s[:, None] * np.asarray(tints, dtype=np.float16).astype(np.float32)).astype(
        np.float16)


def _gaps(keys: np.ndarray) -> np.ndarray:
    """d_j = key_j − key_{j−1} − 1 of increasing int64 ``keys`` (the first: its key)."""
    k = np.asarray(keys, dtype=np.int64)
    return np.diff(k, prepend=-1) - 1


def _bits(d: np.ndarray, k: int) -> tuple[int, int]:
    """Unary and remainder bits of gaps ``d`` at Rice parameter ``k``."""
    return int(np.sum(d >> k)) + d.size, d.size * k


def rice_parameter(gaps: np.ndarray) -> int:
    """The Rice parameter k that codes ``gaps`` (int64 ≥ 0) in the fewest bits."""
    d = np.asarray(gaps, dtype=np.int64)
    if not d.size:
        return 0
    top = int(d.max()).bit_length()
    costs = [sum(_bits(d, k)) for k in range(top + 1)]
    return int(np.argmin(costs))


def compact_bytes(keys: np.ndarray, tints: int = 0) -> int:
    """Bytes of a compact store of entries at the increasing global keys ``keys`` (module
    docstring: bit streams, three E5M2 values each, the header); with ``tints`` points
    tinted, one E5M2 scale each and :data:`TINT_BYTES` a point."""
    d = _gaps(keys)
    values = (1 if tints else 3) * d.size + TINT_BYTES * tints
    if not d.size:
        return HEADER_BYTES + values
    u, r = _bits(d, rice_parameter(d))
    return -(-u // 8) + -(-r // 8) + values + HEADER_BYTES


def pack_keys(keys: np.ndarray) -> tuple[int, np.ndarray, np.ndarray]:
    """Increasing global keys as (k, unary bytes, remainder bytes), MSB first; the unary
    stream is padded with 1 bits (so its zeros are exactly the entries)."""
    d = _gaps(keys)
    k = rice_parameter(d)
    q = d >> k
    ends = np.cumsum(q + 1) - 1  # the 0 that closes each unary part
    unary = np.ones(-(-(int(ends[-1]) + 1) // 8) * 8 if d.size else 0, dtype=np.uint8)
    unary[ends] = 0
    rem = d & ((1 << k) - 1)
    bits = ((rem[:, None] >> np.arange(k - 1, -1, -1)) & 1).astype(np.uint8).ravel()
    return k, np.packbits(unary), np.packbits(bits)


def unpack_keys(k: int, unary: np.ndarray, remainder: np.ndarray, n: int) -> np.ndarray:
    """The ``n`` global keys (int64) of :func:`pack_keys`'s streams. Raises ``ValueError``
    with what does not fit (the stream lengths, the count of entries)."""
    ub = np.unpackbits(np.asarray(unary, dtype=np.uint8))
    ends = np.flatnonzero(ub == 0)
    if ends.size != n:
        raise ValueError(f"the unary stream closes {ends.size} entries, expected {n}")
    used = int(ends[-1]) + 1 if n else 0  # bits up to the last entry's 0
    if ub.size - used >= 8:
        raise ValueError(f"the unary stream has {ub.size // 8} bytes, its entries fill "
                         f"{-(-used // 8)}")  # fmt: skip
    want = -(-n * k // 8)
    if np.asarray(remainder).size != want:
        raise ValueError(f"the remainder stream has {np.asarray(remainder).size} bytes, "
                         f"expected {want} ({n} entries of {k} bits)")  # fmt: skip
    q = np.diff(ends, prepend=-1) - 1
    rb = np.unpackbits(np.asarray(remainder, dtype=np.uint8))[: n * k].reshape(n, k)
    rem = rb.astype(np.int64) @ (np.int64(1) << np.arange(k - 1, -1, -1, dtype=np.int64))
    d = (q.astype(np.int64) << k) | rem
    return np.cumsum(d + 1) - 1

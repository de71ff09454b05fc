"""The compact code of the highlight store's entries: E5M2 corrections and Rice-coded gaps."""

from __future__ import annotations

import itertools

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from sparsebtf.learning.entry_code import (
    HEADER_BYTES,
    TINT_BYTES,
    compact_bytes,
    from_e5m2,
    on_e5m2_grid,
    pack_keys,
    quantise,
    rice_parameter,
    tint,
    tint_scales,
    tinted,
    to_e5m2,
    unpack_keys,
)

#: every finite E5M2 value, by byte (exponent 31 is inf/NaN)
_FINITE = np.array([b for b in range(256) if (b & 0x7C) != 0x7C], dtype=np.uint8)


def test_e5m2_is_the_nearest_value_ties_to_even():
    """Against a search over every finite E5M2 value: the nearest, an even byte on a tie,
    the largest magnitude past the range."""
    rng = np.random.default_rng(0)
    x = np.concatenate([rng.normal(0, 1, 4000) * np.exp2(rng.integers(-18, 17, 4000)),
                        [0.0, -0.0, 1.125, 1.375, 6e4, -6.5e4, 2.0**-17, 3 * 2.0**-17]])
    x16 = np.clip(x, -65504, 65504).astype(np.float16)  # beyond: saturates
    grid = from_e5m2(_FINITE).astype(np.float64)
    dist = np.abs(x16.astype(np.float64)[:, None] - grid[None, :])
    best = dist.min(axis=1, keepdims=True)
    tied = dist == best
    # among the nearest, the even mantissa (low bit 0), and the sign of x (for ±0)
    want = np.empty(x.size, np.uint8)
    for i in range(x.size):
        cand = _FINITE[tied[i]]
        cand = cand[(cand & 0x80) == (0x80 if np.signbit(x16[i]) else 0)] if cand.size > 1 else cand
        even = cand[(cand & 1) == 0]
        want[i] = (even if even.size else cand)[0]
    got = to_e5m2(x)
    np.testing.assert_array_equal(from_e5m2(got).astype(np.float64),
                                  from_e5m2(want).astype(np.float64))
    assert on_e5m2_grid(quantise(x)) and not on_e5m2_grid(np.float16([1.1]))
    # within 12.5 % inside the normal range
    ok = (np.abs(x16) > 2.0**-14) & (np.abs(x16) < 5e4)
    rel = np.abs(quantise(x)[ok].astype(np.float64) / x16[ok].astype(np.float64) - 1)
    assert rel.max() <= 0.125 + 1e-12


def test_e5m2_round_trip_of_every_byte():
    np.testing.assert_array_equal(to_e5m2(from_e5m2(_FINITE)), _FINITE)


@settings(max_examples=60, deadline=None)
@given(st.lists(st.integers(0, 2**40), min_size=0, max_size=300, unique=True))
def test_keys_round_trip_and_counted_bytes(keys):
    keys = np.sort(np.asarray(keys, dtype=np.int64))
    k, unary, rem = pack_keys(keys)
    np.testing.assert_array_equal(unpack_keys(k, unary, rem, keys.size), keys)
    assert compact_bytes(keys) == unary.size + rem.size + 3 * keys.size + HEADER_BYTES
    # tinted: one byte an entry and a binary16 tint a point
    assert compact_bytes(keys, 4) == (unary.size + rem.size + keys.size + 4 * TINT_BYTES
                                      + HEADER_BYTES)


def test_tint_is_the_principal_colour_and_scales_its_nearest_multiples():
    """Residuals along one colour (with noise): the tint is that colour (largest component
    1), no other direction leaves less squared error, and each scale is the residual's
    projection on the E5M2 grid; a correction is binary16(float32 scale · tint)."""
    rng = np.random.default_rng(4)
    colour = np.array([0.95, 0.64, 0.54])  # copper
    r = rng.lognormal(0, 2, 500)[:, None] * colour + rng.normal(0, 0.01, (500, 3))
    t = tint(r).astype(np.float64)
    assert tint(r).dtype == np.float16 and np.max(np.abs(t)) == 1.0
    np.testing.assert_allclose(t, colour / colour.max(), atol=2e-3)

    def left(d):
        d = d / np.linalg.norm(d)
        return np.square(r - (r @ d)[:, None] * d).sum()

    assert all(left(t) <= left(d) * (1 + 1e-9) for d in rng.normal(0, 1, (200, 3)))
    assert all(left(t) <= left(t + e) for e in np.eye(3) * 1e-3)
    s = tint_scales(r, tint(r))
    assert on_e5m2_grid(s)
    exact = r @ t / (t @ t)  # the projection; E5M2's rounding is tested above
    np.testing.assert_array_equal(s, quantise(exact))
    c = tinted(s, np.broadcast_to(tint(r), r.shape))
    assert c.dtype == np.float16
    np.testing.assert_array_equal(
        c, (s.astype(np.float32)[:, None] * tint(r).astype(np.float32)).astype(np.float16))
    assert np.array_equal(tint(np.zeros((3, 3))), np.ones(3, np.float16))
    assert np.sum(tint(-r)) > 0  # the sign makes the sum positive, the scales carry the sign


def test_rice_parameter_is_the_cheapest():
    rng = np.random.default_rng(1)
    gaps = rng.geometric(1 / 500, 2000).astype(np.int64) - 1
    k = rice_parameter(gaps)

    def bits(j):
        return int(np.sum(gaps >> j)) + gaps.size * (1 + j)

    assert all(bits(k) <= bits(j) for j in range(30))
    assert k in (8, 9)  # log2(500 · ln 2) ≈ 8.4 for geometric gaps


def test_bytes_grow_with_each_entry():
    """The encoder's bisection relies on it: adding a key never lowers the code's bytes."""
    rng = np.random.default_rng(2)
    keys = rng.choice(10**6, 3000, replace=False)
    for tints in (0, 7):
        sizes = [compact_bytes(np.sort(keys[:n]), tints) for n in range(0, 3000, 37)]
        assert all(b >= a for a, b in itertools.pairwise(sizes))


def test_a_level_takes_the_most_entries_its_bytes_hold():
    """The encoder's bisection: the store of the first n entries fits the room, n + 1 do not
    (or there are no more); −1 where even the store's header does not fit."""
    from sparsebtf.codec.highlights import _most_entries, _store_bytes

    rng = np.random.default_rng(3)
    glob = rng.choice(10**7, 5000, replace=False).astype(np.int64)  # ranked order, not sorted
    for room in (0, 4, 5, 40, 999, 7777, 20000, 10**6):
        for lobes, tints in itertools.product((False, True), (0, 7)):
            n = _most_entries(glob, room, lobes, tints)
            if n < 0:
                assert lobes and room < HEADER_BYTES
                continue
            assert _store_bytes(glob, n, lobes, tints) <= room
            assert n == glob.size or _store_bytes(glob, n + 1, lobes, tints) > room
    assert _most_entries(glob, 10**6, False, 0) == glob.size
    assert _most_entries(glob, 10**6, False, 7) == glob.size

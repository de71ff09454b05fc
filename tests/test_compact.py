"""runtime/compact.py: each point's coefficients re-indexed over the columns it uses, in
order of first use, with the list lengths every level-of-detail prefix needs."""

import numpy as np
import pytest

from sparsebtf.runtime.compact import compact_layout

SIZES = (4, 3, 13, 11)


def _codes(rng, counts, spread):
    """Packed locations of points with ``counts`` coefficients, columns drawn from the first
    ``spread`` of each mode (few columns: short lists; all: whole modes)."""
    offsets = np.concatenate([[0], np.cumsum(counts)])
    loc = np.stack([rng.integers(0, min(spread, m), offsets[-1]) for m in SIZES], 1)
    packed = (loc[:, 0] | loc[:, 1] << 8 | loc[:, 2] << 16 | loc[:, 3] << 24).astype(np.uint32)
    return offsets, loc, packed


@pytest.mark.parametrize("dense_fraction", [0.0, 0.3, 0.5, 1.0])
@pytest.mark.parametrize("spread", [2, 5, 13])
def test_the_compact_codes_name_the_same_columns(dense_fraction, spread):
    rng = np.random.default_rng(spread)
    counts = rng.integers(0, 40, 9)
    counts[3] = 0  # a point without coefficients
    offsets, loc, packed = _codes(rng, counts, spread)
    lay = compact_layout(offsets, packed, rng.normal(size=packed.size), SIZES, dense_fraction)
    code = lay.code.astype(np.int64)
    need = lay.need.astype(np.int64)
    e, a, b = code & 0xFFFF, (code >> 16) & 0xFF, code >> 24
    n12, n3, n4 = need & 0xFFFFF, (need >> 20) & 0xFFFFF, need >> 40
    lists = {
        "12": (lay.o12, e, n12, SIZES[0] * SIZES[1], loc[:, 0] * SIZES[1] + loc[:, 1],
               lay.pair1 * SIZES[1] + lay.pair2),
        "3": (lay.o3, a, n3, SIZES[2], loc[:, 2], lay.col3),
        "4": (lay.o4, b, n4, SIZES[3], loc[:, 3], lay.col4),
    }  # fmt: skip
    for (off, idx, nd, m, column, cols), widest in zip(lists.values(), lay.widest, strict=True):
        assert widest == max(np.diff(off), default=0)
        assert off[-1] == cols.size and np.all(np.diff(off) >= 0)
        for p in range(counts.size):
            s = slice(offsets[p], offsets[p + 1])
            mine = cols[off[p]:off[p + 1]]
            used = column[s]
            # every coefficient's compact index names its own column
            assert np.array_equal(mine[idx[s]], used)
            if mine.size == m:  # the whole mode, in order: indices are the columns
                assert np.array_equal(mine, np.arange(m)) and np.array_equal(idx[s], used)
                assert np.all(nd[s] == m)
            else:  # the distinct columns in order of first use; a prefix needs a prefix
                _, first = np.unique(used, return_index=True)
                assert np.array_equal(mine, used[np.sort(first)])
                assert np.array_equal(nd[s], np.maximum.accumulate(idx[s]) + 1)
                assert mine.size <= dense_fraction * m


def test_a_point_using_most_of_a_mode_keeps_the_whole_row():
    rng = np.random.default_rng(0)
    offsets, loc, packed = _codes(rng, [200, 3], 13)
    lay = compact_layout(offsets, packed, np.ones(packed.size), SIZES, 0.5)
    # point 0 uses every light column: the row, in order; point 1 three at most: a list
    assert np.array_equal(lay.col3[:13], np.arange(13)) and lay.o3[1] == 13
    assert lay.o3[2] - lay.o3[1] == np.unique(loc[200:, 2]).size
    assert lay.mean_sizes()[1] == pytest.approx((13 + lay.o3[2] - lay.o3[1]) / 2)


@pytest.mark.parametrize("spread", [2, 13])
def test_the_pairs_regroup_every_coefficient_under_its_light_and_view_columns(spread):
    rng = np.random.default_rng(spread)
    counts = rng.integers(0, 40, 7)
    counts[2] = 0
    offsets, _, packed = _codes(rng, counts, spread)
    values = rng.normal(size=packed.size)
    lay = compact_layout(offsets, packed, values, SIZES, 0.5)
    code = lay.code.astype(np.int64)
    assert lay.pstart[0] == 0 and lay.pstart[-1] == packed.size
    assert lay.opair[-1] == lay.pab.size == lay.pstart.size - 1
    for p in range(counts.size):
        s = slice(offsets[p], offsets[p + 1])
        mine = {(int(c & 0xFFFF), int((c >> 16) & 0xFF), int(c >> 24), float(v))
                for c, v in zip(code[s], values[s], strict=True)}  # fmt: skip
        got = set()
        pairs = set()
        for r in range(lay.opair[p], lay.opair[p + 1]):
            a, b = int(lay.pab[r] & 0xFFFF), int(lay.pab[r] >> 16)
            assert (a, b) not in pairs  # one entry per pair
            pairs.add((a, b))
            for t in range(lay.pstart[r], lay.pstart[r + 1]):
                got.add((int(lay.pe12[t]), a, b, float(lay.pvalues[t])))
        assert got == mine
        assert sum(lay.pstart[r + 1] - lay.pstart[r]
                   for r in range(lay.opair[p], lay.opair[p + 1])) == counts[p]  # fmt: skip

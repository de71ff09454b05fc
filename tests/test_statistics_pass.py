"""One read for the statistics and the "auto" log offset (issue 36): the pass on a provisional
offset gives bit for bit the statistics, hence the codes, of choosing the offset first and
reading the sums after, and reads the data once when the provisional offset holds."""

import numpy as np
import pytest

from sparsebtf.codec import encode
from sparsebtf.data.btf import ArrayBTF
from sparsebtf.data.synth import synthesize
from sparsebtf.points import statistics
from sparsebtf.points.statistics import (
    choose_log_offset,
    gather_statistics,
    provisional_log_offset,
    statistics_with_offset,
)

from .conftest import smooth_btf, tiny_model


class CountingBTF(ArrayBTF):
    """An ArrayBTF that counts the values its reads return."""

    read_values = 0

    def read(self, rows, cols, lights, views):  # type: ignore[no-untyped-def]
        out = super().read(rows, cols, lights, views)
        self.read_values += out.size
        return out


def counting(btf: ArrayBTF) -> CountingBTF:
    return CountingBTF(btf.read(*(slice(None),) * 4), btf.lights, btf.views, name=btf.name)


def two_passes(btf, rule="auto"):
    """The statistics as encode gathered them before: the offset first, then the sums."""
    return gather_statistics(btf, log_offset=choose_log_offset(btf, rule), progress=False)


def same(a, b) -> None:
    assert a.log_offset == b.log_offset
    for name in ("mean", "std", "bound"):
        x, y = getattr(a, name), getattr(b, name)
        assert x.dtype == y.dtype and np.array_equal(x, y), name


def black_rows_below(btf: ArrayBTF, row: int) -> ArrayBTF:
    """``btf`` with every row from ``row`` on 1000× darker and a third of it black: the
    first rows' median misses the whole sample's (the provisional offset is wrong)."""
    data = btf.read(*(slice(None),) * 4).copy()
    data[row:] *= 1e-3
    data[row:, ::3] = 0
    return ArrayBTF(data, btf.lights, btf.views, name="split")


@pytest.fixture
def small_bands(monkeypatch):
    """Bands of 2 rows (a few bytes per read), so the provisional offset sees a part only."""
    monkeypatch.setattr(statistics, "STATS_READ_BYTES", 1)


@pytest.mark.parametrize("rule", ["auto", "release", 0.003])
def test_one_pass_equals_two_passes_bit_for_bit(small_bands, rule):
    metal = synthesize("metal", 12, "tiny13", seed=1, black=True)  # true black, HDR
    for btf in (metal, smooth_btf(3), black_rows_below(smooth_btf(4), 2)):
        same(statistics_with_offset(btf, "shared", rule), two_passes(btf, rule))


def test_the_pass_reads_the_data_once_when_the_provisional_offset_holds(small_bands):
    btf = counting(smooth_btf(5, size=12))
    n = btf.n_values
    assert statistics.statistic_bands(btf)[0] < btf.height  # the provisional reads a part
    st = statistics_with_offset(btf)
    assert provisional_log_offset(btf) == st.log_offset
    # one pass, plus the provisional's sample: its first band of 12 of 13 views
    assert n <= btf.read_values <= n * (1 + 2 / 12)
    btf.read_values = 0
    two_passes(btf)
    assert btf.read_values >= n * (1 + 12 / 13)  # before: the offset's sample, then a pass


def test_a_wrong_provisional_offset_is_read_again(small_bands):
    btf = counting(black_rows_below(smooth_btf(6, size=12), 2))
    st = statistics_with_offset(btf)
    assert provisional_log_offset(btf) != st.log_offset == choose_log_offset(btf)
    assert btf.read_values >= 2 * btf.n_values  # the sums again, at the sample's offset
    same(st, two_passes(btf))


def test_encode_codes_equal_those_of_the_offset_chosen_first(small_bands):
    model = tiny_model()
    for btf in (smooth_btf(7), black_rows_below(smooth_btf(8), 2)):
        offset = choose_log_offset(btf)
        one = encode(btf, model, tau=(40, 8, 8), eps=0.0, progress=False)
        # a number is the offset the old first pass chose: one pass at it
        two = encode(btf, model, tau=(40, 8, 8), eps=0.0, progress=False, log_offset=offset)
        same(one.stats, two.stats)
        for ch in one.codes:
            a, b = one.codes[ch], two.codes[ch]
            assert np.array_equal(a.membership, b.membership)
            assert np.array_equal(a.values, b.values) and np.array_equal(a.locations, b.locations)

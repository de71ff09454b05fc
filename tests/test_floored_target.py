"""The linear objective's floored targets (issue 46): under a small log offset the coder also
projects each point with its dark values raised to the point's floor
(:meth:`~sparsebtf.learning.objective.ChannelError.floored`), judged against the true values.

* the floored copy is the encoder's own preprocessing of the floored RGB values, and the floor
  is the automatic log offset's rule on the point's values;
* none where the floor is not above the offset;
* on a noisy material (exact zeros among its values) at the release's offset the codes err
  less in linear RGB than without the floored copies, and the levels stay nested — at fixed
  τ and under rate control.
"""

from __future__ import annotations

import numpy as np
import pytest

from sparsebtf.codec.encode import batch_errors, encode_levels
from sparsebtf.data.btf import ArrayBTF
from sparsebtf.learning.objective import ChannelError
from sparsebtf.points.grid import PatchGrid, iter_points
from sparsebtf.points.preprocessing import Preprocessor
from sparsebtf.points.statistics import offset_of_median

from .conftest import smooth_btf, tiny_model

LEVELS = [(16, 4, 4), (64, 16, 16)]


@pytest.fixture(scope="module")
def model():
    return tiny_model()


def noisy_dark_btf() -> ArrayBTF:
    """``smooth_btf(8)`` as a few-sample capture: 30 % of its values exact zeros."""
    b = smooth_btf(8)
    a = b.to_array() * (np.random.default_rng(5).random(b.to_array().shape) >= 0.3)
    return ArrayBTF(a.astype(np.float32), b.lights, b.views, name="noisy")


def _points(btf, model, stats):
    pre = Preprocessor(stats)
    n = PatchGrid.for_btf(btf, model.patch).n_points
    ((_, x),) = list(iter_points(btf, pre, model.patch, np.arange(n), n, channels_first=True))
    return pre, x


def test_floored_copy_is_the_preprocessed_floored_values(model):
    btf = noisy_dark_btf()
    (coded,) = encode_levels(btf, model, LEVELS[:1], objective="linear", log_offset="release",
                             progress=False)  # fmt: skip
    pre, x = _points(btf, model, coded.stats)
    errors = batch_errors(x, pre, "linear")
    assert errors is not None
    i = 1
    # the point's own RGB values, as the stream cut them
    rgb = np.exp(errors[0].log_rgb[i].astype(np.float64)) - coded.stats.log_offset
    f = errors[0].floor(i)
    assert f == offset_of_median(float(np.median(rgb[rgb > 0])))
    assert f > 100 * coded.stats.log_offset
    lifted = ArrayBTF(np.maximum(btf.to_array(), np.float32(f)), btf.lights, btf.views)
    _, want = _points(lifted, model, coded.stats)
    for c in range(3):
        got = errors[c].floored(i, x[c][i])
        assert got is not None and got.dtype == x.dtype
        np.testing.assert_allclose(got, want[c][i], atol=2e-4)
        # values above the floor keep their standardised value
        above = np.all(rgb > 1.01 * f, axis=-1)
        np.testing.assert_allclose(got[above], x[c][i][above], atol=2e-4)


def test_no_floored_copy_where_the_floor_is_not_above_the_offset():
    log_rgb = np.full((1, 2, 2, 3, 3, 3), np.log(0.5 + 0.01), dtype=np.float32)
    err = ChannelError.for_batch("linear", log_rgb, np.full((3, 3, 1), 0.7), None, 0.01, 0)
    assert err.floor(0) == pytest.approx(0.005)
    assert err.floored(0, np.zeros((2, 2, 3, 3), np.float32)) is None


def _mse(coded, btf) -> float:
    from sparsebtf.runtime.dense import DecodedBTF

    return float(np.square(DecodedBTF(coded).to_array().astype(np.float64)
                           - btf.to_array()).mean())  # fmt: skip


def test_floored_targets_lower_the_linear_error_at_a_small_offset(model, monkeypatch):
    btf = noisy_dark_btf()
    kw = {"objective": "linear", "log_offset": "release", "progress": False}
    with_floor = encode_levels(btf, model, LEVELS, **kw)
    with monkeypatch.context() as m:
        m.setattr(ChannelError, "floored", lambda self, i, x, f=None: None)
        without = encode_levels(btf, model, LEVELS, **kw)
    a = [_mse(c, btf) for c in with_floor]
    b = [_mse(c, btf) for c in without]
    assert a[1] <= a[0]  # nested
    # measured: 0.117 and 0.098 against 0.205 and 0.203
    assert a[0] < 0.7 * b[0] and a[1] < 0.7 * b[1], (a, b)


def test_rate_control_takes_the_floored_copies_too(model, monkeypatch):
    from sparsebtf.codec.rate import encode_rate_levels

    btf = noisy_dark_btf()
    kw = {"objective": "linear", "log_offset": "release", "progress": False}
    with_floor = encode_rate_levels(btf, model, [600, 1500], **kw)
    with monkeypatch.context() as m:
        m.setattr(ChannelError, "floored", lambda self, i, x, f=None: None)
        without = encode_rate_levels(btf, model, [600, 1500], **kw)
    a = [_mse(c, btf) for c in with_floor]
    b = [_mse(c, btf) for c in without]
    assert a[1] <= a[0]
    # measured: 0.104 and 0.098 against 0.136 and 0.138
    assert a[0] < 0.8 * b[0] and a[1] < 0.8 * b[1], (a, b)

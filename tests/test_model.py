"""The τ syntax (one parser) and the Table 4 cost model (one formula)."""

from __future__ import annotations

import numpy as np
import pytest

from sparsebtf.errors import BTFInputError
from sparsebtf.learning.cost import (
    channel_storage,
    coefficient_budget,
    location_width,
    material_bytes,
)
from sparsebtf.model import parse_tau

FULL = {"Y": 100, "U": 10, "V": 9}
NOMINAL = {"Y": 80, "U": 8, "V": 8}


@pytest.mark.parametrize(
    ("tau", "expected"),
    [
        (64, {"Y": 64, "U": 64, "V": 64}),
        (np.int64(5), {"Y": 5, "U": 5, "V": 5}),
        ("885,64,64", {"Y": 885, "U": 64, "V": 64}),
        (" 885 , 64 ,64 ", {"Y": 885, "U": 64, "V": 64}),
        ("32", {"Y": 32, "U": 32, "V": 32}),
        ([7], {"Y": 7, "U": 7, "V": 7}),
        ((3, 2, 1), {"Y": 3, "U": 2, "V": 1}),
        ({"Y": 4, "U": 3, "V": 2, "extra": 9}, {"Y": 4, "U": 3, "V": 2}),
        (12.0, {"Y": 12, "U": 12, "V": 12}),
    ],
)
def test_parse_tau_counts(tau, expected):
    assert parse_tau(tau) == expected
    # the same counts whether or not a coded BTF gives context
    assert parse_tau(tau, full=FULL, nominal=NOMINAL) == expected


def test_parse_tau_fractions_and_all_need_a_coded_btf():
    assert parse_tau(None, full=FULL) == FULL
    assert parse_tau("all", full=FULL) == FULL
    # a fraction of the coded τ (nominal), rounded up, at least 1
    assert parse_tau(0.25, full=FULL, nominal=NOMINAL) == {"Y": 20, "U": 2, "V": 2}
    assert parse_tau("0.25", full=FULL, nominal=NOMINAL) == {"Y": 20, "U": 2, "V": 2}
    assert parse_tau(0.01, full=FULL) == {"Y": 1, "U": 1, "V": 1}
    for tau in (None, "all", 0.5):
        with pytest.raises(BTFInputError, match=r"needed|fraction needs"):
            parse_tau(tau)


@pytest.mark.parametrize(
    ("tau", "why"),
    [
        ("", "not a number"),
        ("x.y", "not a number"),
        ("a,b,c", "not an integer"),
        ("1,2", "one value per channel"),
        ((1.5, 2, 3), "not an integer"),
        (0, ">= 1"),
        ("0,1,1", ">= 1"),
        (True, "not a number"),
        (1.5, "fractional tau must be in"),
        (float("nan"), "fractional tau must be in"),
        ({"Y": 3}, "no value for channel"),
    ],
)
def test_parse_tau_refuses_with_the_value_given(tau, why):
    with pytest.raises(BTFInputError, match=why) as e:
        parse_tau(tau, full=FULL, nominal=NOMINAL)
    assert repr(tau)[:3] in str(e.value)


def test_cost_model_is_one_formula():
    sizes = (10, 10, 151, 151)
    assert location_width(sizes) == 3
    ch = channel_storage(nnz=1000, n_points=40, n_dictionaries=8, mode_sizes=sizes)
    # the per-channel breakdown adds up to the per-material formula plus the dictionaries
    assert ch["bytes_total"] == material_bytes(1000, 40, 1, 3) + ch["bytes_dictionaries"]
    assert ch["bytes_dictionaries"] == 2 * 8 * (100 + 100 + 151**2 + 151**2)
    # the coefficient budget inverts the per-material formula (rounded down)
    for nnz in (0, 1, 999, 123456):
        target = material_bytes(nnz, 1600, 3, 3)
        assert coefficient_budget(target, 1600, 3, 3) == nnz
        assert coefficient_budget(target + 4, 1600, 3, 3) == nnz

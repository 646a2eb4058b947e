"""Mixed-radix phase labels, decoding formula and automatic periods."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from service.encoding.phases import (
    auto_periods,
    index_to_labels,
    labels_to_index,
    place_values,
    validate_periods,
)
from service.errors import InvalidParameterError

periods_st = st.lists(st.integers(2, 12), min_size=1, max_size=4)


def test_paper_worked_example_round_trips_all_twelve_frames() -> None:
    periods = (2, 2, 3)
    labels = index_to_labels(np.arange(12), periods)
    # τ1 is the most significant digit: encoder 1 sees contiguous blocks of 6 frames
    assert labels[:, 0].tolist() == [0] * 6 + [1] * 6
    # the last encoder sees i mod τk
    assert labels[:, 2].tolist() == [i % 3 for i in range(12)]
    assert labels[7].tolist() == [1, 0, 1]  # 7 = 1·6 + 0·3 + 1
    assert labels_to_index(labels, periods).tolist() == list(range(12))


@given(periods=periods_st, data=st.data())
def test_round_trip_for_random_periods(periods: list[int], data: st.DataObject) -> None:
    total = math.prod(periods)
    n = data.draw(st.integers(1, total))
    idx = np.arange(n)
    labels = index_to_labels(idx, periods)
    assert (labels >= 0).all() and (labels < np.asarray(periods)).all()
    assert np.array_equal(labels_to_index(labels, periods), idx)


@given(periods=periods_st)
def test_decode_formula_matches_sum_of_digit_times_place_value(periods: list[int]) -> None:
    vals = place_values(periods)
    for j in range(len(periods)):
        assert vals[j] == math.prod(periods[j + 1 :])


@given(n=st.integers(2, 200_000), k=st.integers(1, 5))
@settings(max_examples=200)
def test_auto_periods_cover_n_with_minimal_balanced_sum(n: int, k: int) -> None:
    if k > math.ceil(math.log2(n)):
        with pytest.raises(InvalidParameterError):
            auto_periods(n, k)
        return
    periods = auto_periods(n, k)
    assert len(periods) == k
    assert all(p >= 2 for p in periods)
    assert math.prod(periods) >= n
    assert max(periods) - min(periods) <= 1  # balanced
    # no vector with a smaller sum covers n: the balanced one with sum − 1 does not
    s = sum(periods) - 1
    if s >= 2 * k:
        q, r = divmod(s, k)
        assert (q + 1) ** r * q ** (k - r) < n


def test_auto_periods_does_not_need_n_to_factorise() -> None:
    assert math.prod(auto_periods(9973, 2)) >= 9973  # a prime
    assert auto_periods(10_000, 2) == (100, 100)
    assert auto_periods(12, 3) == (3, 2, 2)


@pytest.mark.parametrize(
    "periods,n",
    [((1, 5), 5), ((2, 2), 5), ((), 2), ((2.5, 4), 5)],
)
def test_invalid_periods_are_rejected(periods: tuple, n: int) -> None:
    with pytest.raises(InvalidParameterError):
        validate_periods(periods, n)


def test_labels_outside_their_period_are_rejected() -> None:
    with pytest.raises(InvalidParameterError):
        labels_to_index(np.array([[0, 3]]), (2, 3))
    with pytest.raises(InvalidParameterError):
        index_to_labels(np.array([6]), (2, 3))


def test_parse_periods_accepts_commas_and_x_and_names_bad_input() -> None:
    from service.encoding.phases import parse_periods

    assert parse_periods("60,60") == (60, 60) and parse_periods("4x3x2") == (4, 3, 2)
    assert parse_periods(None) is None and parse_periods("") is None
    with pytest.raises(InvalidParameterError, match="--periods must be integers"):
        parse_periods("5,a", "--periods")

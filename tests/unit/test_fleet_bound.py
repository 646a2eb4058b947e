"""The fleet benchmark's lower bound: the work no server can skip, against the gRPC floor."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from service.bench.fleet_bound import compute_per_frame, lower_bound_ratio
from service.bench.grpc_floor import FLEET_TARGET, fleet_efficiency
from service.encoding import ModelParams, build_model
from service.encoding.adaptation import AppearanceAdapter
from service.encoding.synthetic import SyntheticRoute


@pytest.fixture(scope="module")
def model(small_route: SyntheticRoute):
    return build_model(ModelParams()).fit(small_route.reference)  # the default preset


def test_compute_counts_adaptation_and_localization_per_frame(model, small_route) -> None:
    got = compute_per_frame(model, small_route.query, n_streams=3, window=4, rounds=3)
    assert got["batch"] == 12 and got["adapted"] is True
    assert got["adapt_us_per_frame"] > 0 and got["localize_us_per_frame"] > 0
    assert got["compute_us_per_frame"] == pytest.approx(
        got["adapt_us_per_frame"] + got["localize_us_per_frame"])


def test_unadapted_frames_cost_less_to_prepare(model, small_route) -> None:
    adapted = compute_per_frame(model, small_route.query, 4, 8, rounds=5)
    plain = compute_per_frame(model, small_route.query, 4, 8, adapt=False, rounds=5)
    assert plain["adapted"] is False
    assert plain["adapt_us_per_frame"] < adapted["adapt_us_per_frame"]


def test_the_model_is_left_as_it_was(model, small_route) -> None:
    before = model.localize(small_route.query[:50]).index.copy()
    fresh = AppearanceAdapter.for_model(model)
    compute_per_frame(model, small_route.query, 2, 3, rounds=2)
    assert np.array_equal(model.localize(small_route.query[:50]).index, before)
    assert np.array_equal(AppearanceAdapter.for_model(model)._state, fresh._state)


@pytest.mark.parametrize(("streams", "window"), [(0, 4), (4, 0)])
def test_an_empty_fleet_is_refused(model, small_route, streams: int, window: int) -> None:
    with pytest.raises(ValueError, match="at least 1"):
        compute_per_frame(model, small_route.query, streams, window)


@given(st.floats(0.0, 1e4), st.floats(1.0, 1e4), st.floats(0.0, 1e3))
def test_the_bound_is_the_floor_plus_the_compute(compute: float, floor: float, more: float) -> None:
    ratio = lower_bound_ratio(compute, floor)
    assert ratio == pytest.approx((floor + compute) / floor)
    assert ratio >= 1.0
    assert lower_bound_ratio(compute + more, floor) >= ratio


def test_a_floor_without_cost_is_refused() -> None:
    with pytest.raises(ValueError, match="positive"):
        lower_bound_ratio(10.0, 0.0)


def test_fleet_efficiency_reports_the_bound_beside_the_ratio() -> None:
    streams = {"server_cpu_us_per_frame": 250.0, "frames_per_s": 4000.0, "adapted_fraction": 1.0}
    floor = {"server_cpu_us_per_frame": 100.0, "frames_per_s": 9000.0}
    compute = {"compute_us_per_frame": 45.0, "adapt_us_per_frame": 20.0,
               "localize_us_per_frame": 25.0, "batch": 128, "adapted": True}  # fmt: skip
    out = fleet_efficiency(streams, floor, compute)
    assert out["ratio"] == pytest.approx(2.5) and out["target_ratio"] == FLEET_TARGET
    assert out["lower_bound_ratio"] == pytest.approx(1.45)
    assert out["compute"] == compute
    assert "lower_bound_ratio" not in fleet_efficiency(streams, floor)

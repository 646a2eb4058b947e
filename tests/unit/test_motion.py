"""The sequence filter's motion model: stops per direction, the speed walk, mass bookkeeping."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from service.encoding.motion import MotionModel
from service.encoding.sequence_config import SequenceConfig

W = 200


def predict(model: MotionModel, state: np.ndarray) -> np.ndarray:
    out = np.empty_like(state)
    model.predict(state.copy(), out, np.empty_like(state), 1.0)
    return out


def test_a_stopped_state_per_direction_between_the_two_grids() -> None:
    model = MotionModel(SequenceConfig())
    n_dir = SequenceConfig().speeds().size // 2
    assert model.stops == [n_dir, n_dir + 1]
    assert np.array_equal(model.speeds[model.stops], [0.0, 0.0])
    assert np.array_equal(model.speeds, -model.speeds[::-1])  # mirrored: reversing is a flip
    assert model.n_states == SequenceConfig().n_states == 2 * n_dir + 2
    forwards = MotionModel(SequenceConfig(reverse=False))
    assert forwards.stops == [0] and forwards.n_states == SequenceConfig(reverse=False).n_states
    assert MotionModel(SequenceConfig(stop_probability=0.0)).stops == []


@pytest.mark.parametrize("direction", [0, 1])
def test_a_stopped_vehicle_drives_on_the_way_it_came(direction: int) -> None:
    """Mass in the stopped state of one direction moves on to that direction's speeds only
    (but for the direction_change share)."""
    config = SequenceConfig(start_probability=0.5, direction_change=0.0)
    model = MotionModel(config)
    state = np.zeros((model.n_states, W), dtype=np.float32)
    state[model.stops[direction], W // 2] = 1.0
    out = predict(model, state)
    block = model.blocks[direction]
    other = model.blocks[1 - direction]
    assert out[block].sum() == pytest.approx(0.5, rel=1e-6)
    assert out[model.stops[direction]].sum() == pytest.approx(0.5, rel=1e-6)
    assert out[other].sum() == 0.0 and out[model.stops[1 - direction]].sum() == 0.0
    moved = out[block].sum(axis=0)
    frames = np.flatnonzero(moved)
    mean = float(moved @ np.arange(W)) / float(moved.sum())
    if direction == 1:
        assert frames.min() >= W // 2 and mean > W // 2 + 0.5
    else:
        assert frames.max() <= W // 2 and mean < W // 2 - 0.5


def test_a_direction_change_flips_a_stopped_vehicle_too() -> None:
    model = MotionModel(SequenceConfig(direction_change=0.25, stop_probability=0.1))
    state = np.zeros((model.n_states, W), dtype=np.float32)
    state[model.stops[1], W // 2] = 1.0
    out = predict(model, state)
    assert out[model.stops[0]].sum() == pytest.approx(0.25 * out[model.stops].sum(), rel=1e-5)


@settings(max_examples=50, deadline=None)
@given(
    reverse=st.booleans(),
    stop=st.sampled_from([0.0, 0.03, 0.3]),
    start=st.floats(0.05, 1.0),
    change=st.floats(0.0, 1.0),
    flip=st.floats(0.0, 0.5),
    seed=st.integers(0, 2**16),
)
def test_prediction_keeps_the_mass_away_from_the_ends(
    reverse: bool, stop: float, start: float, change: float, flip: float, seed: int
) -> None:
    """Mass neither appears nor vanishes while it stays on the array (the largest speed is 2
    frames, so a state 10 frames from either end stays on it)."""
    config = SequenceConfig(reverse=reverse, stop_probability=stop, start_probability=start,
                            speed_change=change, direction_change=flip)  # fmt: skip
    model = MotionModel(config)
    state = np.zeros((model.n_states, W), dtype=np.float32)
    state[:, 10:-10] = np.random.default_rng(seed).random((model.n_states, W - 20))
    out = predict(model, state)
    assert (out >= 0).all()
    assert out.sum(dtype=np.float64) == pytest.approx(state.sum(dtype=np.float64), rel=1e-5)


@pytest.mark.parametrize("direction", [0, 1])
def test_a_speed_jump_reaches_every_speed_of_the_direction_at_once(direction: int) -> None:
    """With ``speed_jump``, mass at one speed spreads to every speed of its direction in one
    frame (evenly, that share), never to the other direction; without it, only to the
    neighbours."""
    jump = 0.2
    for config, spread in ((SequenceConfig(speed_jump=jump, stop_probability=0.0,
                                           direction_change=0.0, speed_change=0.0), True),
                           (SequenceConfig(speed_jump=0.0, stop_probability=0.0,
                                           direction_change=0.0), False)):
        model = MotionModel(config)
        block = model.blocks[direction]
        state = np.zeros((model.n_states, W), dtype=np.float32)
        state[block.start, W // 2] = 1.0  # the direction's first grid speed
        out = predict(model, state)
        per_speed = out.sum(axis=1)
        n = block.stop - block.start
        assert per_speed[model.blocks[1 - direction]].sum() == 0.0
        assert per_speed.sum() == pytest.approx(1.0, rel=1e-6)
        if spread:
            assert per_speed[block.start] == pytest.approx(1 - jump + jump / n, rel=1e-5)
            assert per_speed[block.start + 1 : block.stop] == pytest.approx(
                np.full(n - 1, jump / n), rel=1e-5)
        else:
            assert (per_speed[block.start + 2 : block.stop] == 0).all()


@settings(max_examples=30, deadline=None)
@given(jump=st.floats(0.0, 1.0), stop=st.sampled_from([0.0, 0.02]), seed=st.integers(0, 2**16))
def test_a_speed_jump_keeps_the_mass(jump: float, stop: float, seed: int) -> None:
    model = MotionModel(SequenceConfig(speed_jump=jump, stop_probability=stop))
    state = np.zeros((model.n_states, W), dtype=np.float32)
    state[:, 10:-10] = np.random.default_rng(seed).random((model.n_states, W - 20))
    out = predict(model, state)
    assert (out >= 0).all()
    assert out.sum(dtype=np.float64) == pytest.approx(state.sum(dtype=np.float64), rel=1e-5)

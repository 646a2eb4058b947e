"""Repeated views in the sequence filter: a stop's repeats are not new evidence of the place
(the default), and with ``repeat_speed`` evidence of a low speed (SYNTHETIC scores)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from service.encoding.motion import MotionModel
from service.encoding.repeats import (
    NEW,
    Repeat,
    RepeatDetector,
    repeat_probability,
    standardised,
    successors,
)
from service.encoding.sequence import (
    SequenceConfig,
    apply_evidence,
    filter_sequence,
    mean_evidence,
)
from service.encoding.tracking import track_scores

N = 600
CONFIG = SequenceConfig(repeat_novelty=1e-3, repeat_speed=True)  # repeats read, speed too
OFF = SequenceConfig(repeat_novelty=0.0)  # every frame new evidence
SPEEDS = MotionModel(CONFIG).speeds
finite_rows = arrays(np.float64, st.integers(8, 64),
                     elements=st.floats(-1e3, 1e3, allow_nan=False, allow_infinity=False))  # fmt: skip


def observe(det: RepeatDetector, row: np.ndarray) -> Repeat:
    """``det``'s reading of a query whose scores over a route of ``row.size`` frames are
    ``row``, at every frame as the sample (and their successors)."""
    frames = np.arange(row.size)
    return det.observe(row[frames], row[successors(frames, row.size)])


def bumps(truth: np.ndarray, noise: float, seed: int,
          alias: tuple[int, float] | None = None) -> np.ndarray:  # fmt: skip
    """SYNTHETIC frame scores: a bump at each true frame (and at an alias) over noise."""
    f = np.arange(N)[None, :]
    S = np.exp(-0.5 * ((f - np.asarray(truth, float)[:, None]) / 3.0) ** 2)
    if alias is not None:
        S += alias[1] * np.exp(-0.5 * ((f - alias[0]) / 3.0) ** 2)
    return S + np.random.default_rng(seed).normal(0.0, noise, S.shape)


def stop_at_an_alias(copy_noise: float) -> tuple[np.ndarray, np.ndarray]:
    """A drive that stops 30 frames at frame 300, whose view there scores best 20 frames on
    (an alias): the stop's frames are that view with camera noise of ``copy_noise``."""
    view = bumps(np.array([300]), 0.2, 1, alias=(320, 1.3))[0]
    rng = np.random.default_rng(2)
    stop = np.stack([view + rng.normal(0.0, copy_noise, N) for _ in range(30)])
    S = np.concatenate([bumps(np.arange(100, 300), 0.5, 0), stop,
                        bumps(np.arange(301, 400), 0.5, 3)])  # fmt: skip
    return S, np.r_[np.arange(100, 300), [300] * 30, np.arange(301, 400)]


@pytest.mark.parametrize("copy_noise", [0.0, 1e-3])
def test_a_stop_is_not_dragged_to_an_alias_by_its_repeated_view(copy_noise: float) -> None:
    S, truth = stop_at_an_alias(copy_noise)
    stop = slice(200, 260)  # the stop and the 30 frames after it
    got = filter_sequence(S, CONFIG).index
    assert (np.abs(got[stop] - truth[stop]) <= 5).mean() == 1.0
    # every repeat as new evidence: the belief goes to the alias during the stop
    old = filter_sequence(S, OFF).index
    assert (np.abs(old[stop] - truth[stop]) <= 5).mean() < 0.9


@pytest.mark.parametrize("copy_noise", [0.0, 1e-3])
def test_the_default_tempers_a_stops_repeats_without_reading_the_speed(copy_noise: float) -> None:
    S, truth = stop_at_an_alias(copy_noise)
    default = SequenceConfig()
    assert default.repeat_novelty > 0 and not default.repeat_speed
    for tracking in (False, True):
        got = filter_sequence(S, default.model_copy(update={"tracking": tracking})).index
        # arriving, the belief may coast a frame past ±5 before it holds; it never reaches the
        # alias, where every repeat as new evidence takes it
        assert (np.abs(got[200:260] - truth[200:260]) <= 5).mean() >= 0.95, tracking
        assert not (np.abs(got[200:230] - 320) <= 5).any(), tracking
    old = filter_sequence(S, OFF).index
    assert (np.abs(old[200:230] - 320) <= 5).any()
    det = RepeatDetector(SPEEDS, default)
    row = np.random.default_rng(0).normal(size=256)
    observe(det, row)
    assert observe(det, row.copy()) == Repeat(0.0, None)  # a repeat: no place evidence, no speed
    assert observe(det, np.random.default_rng(1).normal(size=256)) is NEW


def test_a_stop_whose_frames_differ_is_read_by_the_default_as_without_repeats() -> None:
    """A stopped camera whose frames differ more than a one-frame move's change of the scores
    sends new views: the default reads them as every frame new, where the speed reading counts
    them against stopping."""
    S, _ = stop_at_an_alias(0.5)
    np.testing.assert_array_equal(filter_sequence(S).index, filter_sequence(S, OFF).index)


def test_the_windowed_tracker_reads_repeats_as_the_whole_filter_does() -> None:
    S, truth = stop_at_an_alias(1e-3)
    whole = filter_sequence(S, CONFIG.model_copy(update={"tracking": False})).index
    tracked = np.array([e.index for e in track_scores(S, CONFIG)])
    assert (np.abs(tracked[200:260] - truth[200:260]) <= 5).all()
    assert (np.abs(whole[200:260] - truth[200:260]) <= 5).all()


def test_a_repeat_weighs_stopping_and_a_new_view_moving() -> None:
    det = RepeatDetector(SPEEDS, CONFIG)
    row = np.random.default_rng(0).normal(size=256)
    assert observe(det, row) is NEW  # nothing to compare the first frame to
    same = observe(det, row.copy())
    assert same.weight == 0.0
    assert same.speed is not None
    p = repeat_probability(SPEEDS, CONFIG)
    np.testing.assert_allclose(same.speed, p, rtol=1e-6)
    new = observe(det, np.random.default_rng(1).normal(size=256))
    assert new.weight == 1.0 and new.speed is not None
    np.testing.assert_allclose(new.speed, 1.0 - p, rtol=1e-6)
    stopped, fast = SPEEDS == 0, np.abs(SPEEDS) >= 1
    assert same.speed[stopped].min() > same.speed[fast].max()
    assert new.speed[stopped].max() < new.speed[fast].min()


def test_repeats_off_make_every_frame_new_evidence() -> None:
    det = RepeatDetector(SPEEDS, OFF)
    row = np.arange(10.0)
    assert observe(det, row) is NEW and observe(det, row) is NEW


def test_novelty_is_measured_in_one_frame_moves_of_the_scores() -> None:
    """A query whose scores are smooth along the route (its one-frame move changes them
    little) and one whose scores are rough, each followed by the same share of a one-frame
    move: the same novelty, whatever the smoothness."""
    rng = np.random.default_rng(3)
    for width in (1.0, 8.0):
        kernel = np.exp(-0.5 * (np.arange(-25, 26) / width) ** 2)
        row = np.convolve(rng.normal(size=600), kernel, mode="same")
        cfg = SequenceConfig(repeat_novelty=1.0, repeat_speed=True)  # r = 1 − novelty
        det = RepeatDetector(SPEEDS, cfg)
        observe(det, row)
        moved = observe(det, np.roll(row, 1))  # the query one frame further on
        assert moved.weight == pytest.approx(1.0, abs=0.05), width


def test_a_view_between_a_repeat_and_a_move_is_no_evidence_with_move_novelty() -> None:
    cfg = SequenceConfig(repeat_novelty=1e-3, repeat_speed=True, move_novelty=0.2)
    rng = np.random.default_rng(5)
    kernel = np.exp(-0.5 * (np.arange(-25, 26) / 4.0) ** 2)
    row = np.convolve(rng.normal(size=600), kernel, mode="same")
    for shift, want in [(0.05, "neither"), (1.0, "new")]:
        det = RepeatDetector(SPEEDS, cfg)
        observe(det, row)
        frames = np.arange(row.size, dtype=float)
        got = observe(det, np.interp(frames - shift, frames, row))  # the view moved on a bit
        assert got.weight == 1.0 and got.speed is not None
        if want == "neither":
            np.testing.assert_allclose(got.speed, 1.0)
        else:
            np.testing.assert_allclose(got.speed, 1.0 - repeat_probability(SPEEDS, cfg), rtol=1e-6)


def test_a_flat_row_carries_no_repetition() -> None:
    det = RepeatDetector(SPEEDS, CONFIG)
    assert observe(det, np.zeros(16)) is NEW
    assert observe(det, np.zeros(16)) is NEW
    assert standardised(np.full(8, -np.inf)) is None


@given(finite_rows, st.floats(0.01, 100.0), st.floats(-100.0, 100.0))
@settings(max_examples=60, deadline=None)
def test_repetition_is_invariant_to_a_positive_affine_change_of_the_scores(
    row: np.ndarray, a: float, b: float
) -> None:
    first, second = RepeatDetector(SPEEDS, CONFIG), RepeatDetector(SPEEDS, CONFIG)
    nxt = row[::-1].copy()
    observe(first, row)
    observe(second, a * row + b)
    r1, r2 = observe(first, nxt), observe(second, a * nxt + b)
    if r1 is NEW or r2 is NEW:  # flat rows (up to float rounding of the change) compare to nothing
        return
    assert r1.weight == pytest.approx(r2.weight, abs=1e-6)


@given(finite_rows, finite_rows)
@settings(max_examples=60, deadline=None)
def test_repetition_weights_stay_probabilities(a: np.ndarray, b: np.ndarray) -> None:
    det = RepeatDetector(SPEEDS, CONFIG)
    observe(det, a)
    r = observe(det, np.resize(b, a.shape))
    assert 0.0 <= r.weight <= 1.0
    if r.speed is not None:
        assert r.speed.shape == SPEEDS.shape
        assert ((r.speed > 0) & (r.speed < 1)).all()


@given(st.floats(0.0, 1.0), st.floats(0.01, 0.99), st.floats(0.01, 0.99))
def test_the_repeat_probability_falls_from_stopped_to_moving(r: float, ps: float,
                                                             pm: float) -> None:  # fmt: skip
    cfg = SequenceConfig(repeat_stopped=ps, repeat_moving=pm)
    v = np.linspace(-2.0, 2.0, 33)
    p = repeat_probability(v, cfg)
    assert p[16] == pytest.approx(ps) and p[0] == pytest.approx(pm) and p[-1] == pytest.approx(pm)
    d = np.diff(p[16:])
    assert ((d <= 1e-12) if ps >= pm else (d >= -1e-12)).all()


@given(st.floats(0.0, 1.0), st.integers(0, 2**31 - 1))
@settings(max_examples=40, deadline=None)
def test_evidence_tempers_only_the_stopped_states(w: float, seed: int) -> None:
    rng = np.random.default_rng(seed)
    S = SPEEDS.size
    pred = rng.random((S, 20)).astype(np.float32)
    lik = rng.uniform(1e-3, 1.0, 20).astype(np.float32)
    speed = rng.uniform(0.1, 1.0, S).astype(np.float32)
    stops = MotionModel(CONFIG).stops
    out = np.empty_like(pred)
    apply_evidence(pred, lik, Repeat(w, speed), stops, out=out)
    want = pred * lik[None, :]
    want[stops] = pred[stops] * lik[None, :] ** np.float32(w)
    want *= speed[:, None]
    np.testing.assert_allclose(out, want, rtol=1e-5)
    in_place = pred.copy()
    apply_evidence(in_place, lik, Repeat(w, speed), stops, out=in_place)
    np.testing.assert_allclose(in_place, out, rtol=1e-6)
    # a mass spread evenly over the states at likelihood l: the mean evidence
    flat = np.full((S, 1), 1.0 / S, dtype=np.float32)
    got = np.empty_like(flat)
    apply_evidence(flat, lik[:1], Repeat(w, speed), stops, out=got)
    assert mean_evidence(float(lik[0]), Repeat(w, speed), S, stops) == pytest.approx(
        float(got.sum()), rel=1e-5)
    np.testing.assert_allclose(apply_evidence_new(pred, lik, stops), pred * lik[None, :])


def apply_evidence_new(pred: np.ndarray, lik: np.ndarray, stops: list[int]) -> np.ndarray:
    out = np.empty_like(pred)
    apply_evidence(pred, lik, NEW, stops, out=out)
    return out


def test_a_code_models_drive_with_a_stop_reads_its_repeats_through_the_code_scorer() -> None:
    from service.encoding.encoder import PhaseEncoder
    from service.encoding.sequence import sequence_localize
    from service.encoding.synthetic import smooth_route

    route = smooth_route(600, 32, seed=3)
    model = PhaseEncoder(trainer="prototype", code="residue", n_patterns=2, code_ratio=0.2).fit(
        route.reference
    )
    rows = np.r_[np.arange(100, 250), [250] * 20, np.arange(251, 400)]  # a stop at frame 250
    Q = route.query[rows]
    tracked = sequence_localize(model, Q, CONFIG)
    whole = sequence_localize(model, Q, CONFIG.model_copy(update={"tracking": False}))
    assert (np.abs(tracked.index - whole.index) <= 2).mean() > 0.95
    assert (np.abs(tracked.index[150:170] - 250) <= 5).all()  # held through the stop
    assert tracked.speed[165] < 0.5 < tracked.speed[-1]  # stopped, then moving again


def test_frames_with_odometry_are_read_as_new() -> None:
    """Odometry moves every state by the measured displacement: the speed states say nothing
    about the motion, so the repeat reading leaves such a drive as it was."""
    S, truth = stop_at_an_alias(0.0)
    u = np.diff(truth, prepend=truth[:1]).astype(float)
    for tracking in (False, True):
        on = CONFIG.model_copy(update={"tracking": tracking})
        off = on.model_copy(update={"repeat_novelty": 0.0})
        np.testing.assert_array_equal(filter_sequence(S, on, odometry=u).index,
                                      filter_sequence(S, off, odometry=u).index)  # fmt: skip

"""The drive generators and metrics of ``gridplace bench drive`` (no model involved)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from service.bench import drive_metrics as dm
from service.bench import drive_protocols as dp
from service.errors import InvalidParameterError

N = 1000
ALIGNED = np.arange(N, dtype=np.int64)
SHIFTED = np.arange(N, dtype=np.int64) // 2 + 7  # a ground truth that is not the identity


def _runs(x: np.ndarray) -> list[tuple[int, int]]:
    """(value, run length) of consecutive equal entries."""
    edges = np.flatnonzero(np.r_[True, np.diff(x) != 0, True])
    return [(int(x[a]), int(b - a)) for a, b in zip(edges[:-1], edges[1:], strict=True)]


def test_whole_and_reverse_drives_follow_the_ground_truth() -> None:
    (w,) = dp.whole(100, 400, SHIFTED)
    assert np.array_equal(w.rows, np.arange(100, 400))
    assert np.array_equal(w.truth, SHIFTED[100:400])
    (r,) = dp.reverse(100, 400, ALIGNED)
    assert np.array_equal(r.rows, np.arange(399, 99, -1))
    assert np.array_equal(r.truth, r.rows)
    assert r.motion[0] == 0 and np.all(r.motion[1:] == -1)


def test_short_drives_start_at_random_inside_the_part_and_are_seeded() -> None:
    ds = dp.short(500, 1000, ALIGNED, count=50, length=40, seed=3)
    assert len(ds) == 50 and all(len(d) == 40 for d in ds)
    assert all(d.rows[0] >= 500 and d.rows[-1] < 1000 for d in ds)
    assert all(np.array_equal(np.diff(d.rows), np.ones(39)) for d in ds)
    assert len({int(d.rows[0]) for d in ds}) > 10
    again = dp.short(500, 1000, ALIGNED, count=50, length=40, seed=3)
    assert all(np.array_equal(a.rows, b.rows) for a, b in zip(ds, again, strict=True))
    with pytest.raises(InvalidParameterError):
        dp.short(0, 30, ALIGNED, count=1, length=40, seed=0)


def test_a_kidnap_jumps_far_and_the_wheels_do_not_see_it() -> None:
    for d in dp.kidnap(0, N, ALIGNED, count=30, before=100, after=150, min_jump=200, seed=1):
        assert len(d) == 250 and d.event == 100
        assert np.all(np.diff(d.rows[:100]) == 1) and np.all(np.diff(d.rows[100:]) == 1)
        assert abs(int(d.truth[100]) - int(d.truth[99])) >= 200
        assert np.all(d.motion[1:] == 1)  # odometry reports its usual step across the jump
        assert d.rows.min() >= 0 and d.rows.max() < N


@pytest.mark.parametrize("profile", list(dp.SPEED_PROFILES))
def test_speed_profiles_stay_in_the_speed_range(profile: str) -> None:
    v = dp.SPEED_PROFILES[profile](np.random.default_rng(0), 2000)
    assert v.shape == (2000,)
    assert v.min() >= dp.MIN_SPEED - 1e-9 and v.max() <= dp.MAX_SPEED + 1e-9
    assert np.ptp(v) > 0.5  # the speed really varies


def test_stops_repeat_one_frame_for_5_to_20_frames() -> None:
    rng = np.random.default_rng(4)
    v = dp.with_stops(np.full(3000, 1.0), rng)
    zero_runs = [n for val, n in _runs((v == 0).astype(np.int64)) if val == 1]
    assert len(zero_runs) >= 10
    assert all(dp.STOP_FRAMES[0] <= n <= dp.STOP_FRAMES[1] for n in zero_runs)
    rows = dp.positions(0, v, 10_000)
    repeats = [n for _, n in _runs(rows) if n > 1]
    # at speed 1 a frame repeats only at a stop: the frame before it and the stopped ones
    assert sorted(repeats) == sorted(n + 1 for n in zero_runs)


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 10_000), lo=st.integers(0, 300))
def test_variable_speed_drives_resample_the_route(seed: int, lo: int) -> None:
    hi = lo + 600
    for d in dp.speed(lo, hi, SHIFTED, count=2, frames=400, seed=seed):
        assert 1 <= len(d) <= 400
        assert d.rows.min() >= lo and d.rows.max() < hi
        steps = np.diff(d.rows)
        assert steps.min() >= 0 and steps.max() <= 3  # forward, at most 2 frames a step (+ rounding)
        assert np.array_equal(d.truth, SHIFTED[d.rows])  # truth of a resampled drive
        assert np.array_equal(d.motion[1:], np.diff(d.truth))
        assert (steps == 0).any()  # it stops


def test_noisy_odometry_is_exact_at_zero_and_noisy_as_stated() -> None:
    motion = np.full(20_000, 1.0)
    assert np.array_equal(dp.noisy_odometry(motion, 0.0, 1), motion)
    odo = dp.noisy_odometry(motion, 0.1, 1)
    # d(1 + s e1) + s e2 with d = 1: standard deviation s·√2
    assert abs(odo.mean() - 1.0) < 0.01 and abs(odo.std() - 0.1 * np.sqrt(2)) < 0.01
    assert np.array_equal(odo, dp.noisy_odometry(motion, 0.1, 1))


# -- metrics -----------------------------------------------------------------------------------
def test_precision_after_and_l90_on_hand_made_tracks() -> None:
    truth = np.arange(10)
    right = truth.copy()
    late = np.where(truth < 4, 100, truth)  # wrong for the first 4 frames
    never = np.full(10, 100)
    curve = dm.precision_after([right] * 8 + [late, never], [truth] * 10)
    assert np.allclose(curve[:4], 0.8) and np.allclose(curve[4:], 0.9)
    assert dm.first_reaching(curve) == 5
    assert dm.first_reaching(curve, 0.95) is None
    assert dm.precision([right, never], [truth, truth]) == 0.5


def test_kidnap_recovery_counts_frames_until_the_track_stays_right() -> None:
    truth = np.arange(100)
    pred = truth.copy()
    pred[50:60] = 0  # lost for 10 frames after the jump at 50
    pred[65] = 0  # one more slip: not yet staying right
    assert dm.recovery(pred, truth, 50, hold=20) == 16
    assert dm.recovery(pred, truth, 50, hold=5) == 10
    assert dm.recovery(truth, truth, 50) == 0
    assert dm.recovery(np.zeros(100, np.int64), truth, 50) is None
    late = truth.copy()
    late[50:95] = 0
    assert dm.recovery(late, truth, 50, hold=20) == 45  # right to the end counts
    s = dm.recovery_summary([0, 10, 20, None])
    assert s["median"] == 10 and s["never"] == 0.25 and s["drives"] == 4
    assert s["p90"] == pytest.approx(18.0)


def test_traffic_brakes_into_long_stops_and_cruises_beyond_the_default_grid() -> None:
    v = dp.traffic_speeds(np.random.default_rng(5), 5000)
    assert v.shape == (5000,) and v.min() >= 0.0 and v.max() <= dp.TRAFFIC_SPEEDS[1] + 1e-9
    assert v.max() > 2.0 and ((v > 0) & (v < 0.5)).any()  # faster than 2, creeping below 0.5
    stops = [n for val, n in _runs((v == 0).astype(np.int64)) if val == 1]
    assert len(stops) >= 10 and all(dp.TRAFFIC_STOPS[0] <= n <= dp.TRAFFIC_STOPS[1] for n in stops)
    assert np.abs(np.diff(v)).max() < 0.35  # ramps, no jumps in speed


def test_a_stopped_vehicle_sends_near_identical_copies_in_turn() -> None:
    rows = np.array([5, 6, 6, 6, 6, 7, 7, 8])
    got = dp.near_identical(rows, 100, copies=2)
    assert got.tolist() == [5, 6, 106, 206, 6, 7, 107, 8]
    assert (np.diff(got) != 0).all()  # never the same row twice in a row


@settings(max_examples=20, deadline=None)
@given(seed=st.integers(0, 10_000))
def test_traffic_drives_index_the_copies_with_the_recorded_truth(seed: int) -> None:
    truth = np.arange(4000, dtype=np.int64) // 2 + 7
    for d in dp.traffic(100, 4000, truth, count=2, frames=500, seed=seed):
        recorded = d.rows % 4000
        assert d.rows.max() < 4000 * (dp.COPIES + 1) and recorded.min() >= 100
        assert np.array_equal(d.truth, truth[recorded])
        assert np.diff(recorded).min() >= 0 and (np.diff(recorded) == 0).any()  # it stops


def test_precision_interval_resamples_whole_drives() -> None:
    truths = [np.arange(100), np.arange(100), np.arange(50)]
    perfect = [t.copy() for t in truths]
    assert dm.precision_interval(perfect, truths) == (1.0, 1.0)
    assert dm.precision_interval(perfect[:1], truths[:1]) is None  # one drive: no interval
    # one drive all wrong, two all right: an interval around the pooled 150/250, inside [0, 1],
    # whose ends are pooled precisions of some resample of the drives
    mixed = [truths[0] + 50, truths[1], truths[2]]
    lo, hi = dm.precision_interval(mixed, truths, resamples=4000, seed=3)  # type: ignore[misc]
    assert 0.0 <= lo < dm.precision(mixed, truths) < hi <= 1.0
    assert dm.precision_interval(mixed, truths, resamples=4000, seed=3) == (lo, hi)  # seeded
    assert dm.precision_interval(mixed, truths, level=0.5) is not None


@settings(max_examples=40, deadline=None)
@given(st.lists(st.tuples(st.integers(1, 40), st.integers(0, 40)), min_size=2, max_size=8),
       st.integers(0, 2**31 - 1))  # fmt: skip
def test_precision_interval_brackets_the_drives_precisions(drives: list[tuple[int, int]],
                                                           seed: int) -> None:  # fmt: skip
    """Every resample pools some of the drives, so the interval lies between the lowest and
    the highest precision of a single drive."""
    truths = [np.arange(n) for n, _ in drives]
    preds = [np.where(np.arange(n) < min(k, n), np.arange(n), np.arange(n) + 99) for n, k in drives]
    per_drive = [dm.precision([p], [t]) for p, t in zip(preds, truths, strict=True)]
    lo, hi = dm.precision_interval(preds, truths, resamples=200, seed=seed)  # type: ignore[misc]
    assert min(per_drive) - 1e-12 <= lo <= hi <= max(per_drive) + 1e-12

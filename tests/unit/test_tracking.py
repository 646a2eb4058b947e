"""The windowed tracker, odometry and the motion model for real driving (SYNTHETIC scores)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from service.encoding.drive_scoring import CodeScorer, MatrixScorer, drive_scorer, route_sample
from service.encoding.encoder import PhaseEncoder
from service.encoding.repeats import successors
from service.encoding.sequence import (
    SequenceConfig,
    SequenceFilter,
    check_odometry,
    filter_sequence,
    sequence_localize,
)
from service.encoding.synthetic import smooth_route
from service.encoding.tracking import DriveTracker
from service.errors import InvalidInputError

N = 2000


def bumps(truth: np.ndarray, n: int = N, noise: float = 0.5, height: float = 1.0,
          seed: int = 0) -> np.ndarray:  # fmt: skip
    """SYNTHETIC frame scores: a bump at each true frame over Gaussian noise."""
    frames = np.arange(n)[None, :]
    S = height * np.exp(-0.5 * ((frames - np.asarray(truth, float)[:, None]) / 3.0) ** 2)
    return S + np.random.default_rng(seed).normal(0.0, noise, S.shape)


def within(est: np.ndarray, truth: np.ndarray, r: int = 5) -> np.ndarray:
    return np.abs(np.asarray(est) - np.asarray(truth)) <= r


def test_windowed_tracking_equals_the_whole_filter_where_the_belief_is_concentrated() -> None:
    rng = np.random.default_rng(1)
    truth = np.rint(300 + np.cumsum(rng.uniform(0.5, 2.0, 600))).astype(int)
    S = bumps(truth, noise=0.3, seed=1)
    whole = filter_sequence(S, SequenceConfig(tracking=False))
    tracked = filter_sequence(S, SequenceConfig(tracking=True))
    assert within(whole.index, truth).mean() > 0.98
    agree = np.abs(whole.index - tracked.index) <= 1
    assert agree[20:].mean() > 0.98
    # the tracker's z-score comes from a sample of the route: equal up to near-ties
    gap = np.abs(whole.confidence[-100:] - tracked.confidence[-100:])
    assert np.median(gap) < 0.01 and np.mean(gap <= 0.02) >= 0.98, np.sort(gap)[-5:]


def test_the_tracker_holds_only_windows_once_localised() -> None:
    truth = np.arange(100, 700)
    S = bumps(truth, noise=0.3, seed=2)
    tracker = DriveTracker(MatrixScorer(S))
    modes = [tracker.update(t) and tracker.mode for t in range(len(S))]
    assert modes[0] == "whole" and modes[-1] == "windows"
    assert modes.count("windows") > 0.9 * len(S)
    assert tracker.nbytes < tracker.max_nbytes / 4  # a few windows, not the route
    post = tracker.posterior
    assert post.shape == (N,) and abs(post.sum() - 1) < 1e-9 and abs(int(post.argmax()) - 699) <= 2


def _recovered_after(ok: np.ndarray) -> int:
    """Frames until the estimate is right from there to the end."""
    assert ok[-1]
    return ok.size - int(np.argmin(ok[::-1]))


def test_a_kidnapped_vehicle_is_found_again_by_the_global_checks() -> None:
    truth = np.concatenate([np.arange(200, 400), np.arange(1500, 1700)])  # moved at t = 200
    S = bumps(truth, noise=0.5, seed=3)
    tracker = DriveTracker(MatrixScorer(S))
    est = np.array([tracker.update(t).index for t in range(len(S))])
    assert within(est[20:200], truth[20:200]).all()
    back = _recovered_after(within(est[200:], truth[200:]))
    whole = within(filter_sequence(S, SequenceConfig(tracking=False)).index[200:], truth[200:])
    # no slower than the whole filter, but for the wait until the next global check
    assert back <= _recovered_after(whole) + tracker.check_interval, back


def test_stops_and_speed_changes_are_followed_by_default() -> None:
    t = np.arange(600)
    speed = 1.25 + 0.75 * np.sin(t / 30.0)  # 0.5 … 2 frames per query frame, gradually
    speed[200:230] = 0.0  # a stop
    speed[400:410] = 0.0  # and a shorter one
    truth = np.rint(100 + np.cumsum(speed)).astype(int)
    S = bumps(truth, noise=0.5, seed=4)
    got = filter_sequence(S)
    assert within(got.index[20:], truth[20:]).mean() > 0.9
    # the former defaults: forwards only, no stopped state, rare speed changes by steps only
    no_stops = SequenceConfig(stop_probability=0.0, reverse=False, speed_change=0.01,
                              speed_jump=0.0)  # fmt: skip
    stepping = within(filter_sequence(S, no_stops).index[20:], truth[20:]).mean()
    assert stepping < 0.7
    # speed jumps alone take the belief back to the vehicle's speed after each stop sooner
    jumping = no_stops.model_copy(update={"speed_jump": 0.01})
    assert within(filter_sequence(S, jumping).index[20:], truth[20:]).mean() > stepping + 0.1


def test_a_noiseless_drive_with_exact_odometry_is_tracked_exactly_without_evidence() -> None:
    rng = np.random.default_rng(5)
    steps = rng.choice([0.0, 1.0, 2.0, -1.0], size=500)  # stops and reversing too
    truth = (800 + np.cumsum(np.r_[0.0, steps[1:]])).astype(int)
    S = np.zeros((500, N))  # uninformative frames …
    S[np.arange(15), truth[:15]] = 10.0  # … after a short warm-up
    exact = SequenceConfig(odometry_noise=0.0, odometry_floor=0.0)
    odometry = np.r_[0.0, steps[1:]]
    for tracking in (False, True):
        got = filter_sequence(S, exact.model_copy(update={"tracking": tracking}), odometry)
        np.testing.assert_array_equal(got.index[15:], truth[15:])
    without = filter_sequence(S, exact)
    assert within(without.index[100:], truth[100:]).mean() < 0.5


def test_noisy_odometry_helps_on_weak_evidence() -> None:
    rng = np.random.default_rng(6)
    speed = rng.uniform(0.5, 2.0, 800)
    pos = 50 + np.cumsum(speed)
    truth = np.rint(pos).astype(int)
    S = bumps(truth, noise=1.2, seed=6)  # single frames mostly wrong
    measured = np.diff(np.r_[50.0, pos]) * (1 + rng.normal(0, 0.1, 800))
    without = within(filter_sequence(S).index, truth).mean()
    with_odo = within(filter_sequence(S, odometry=measured).index, truth).mean()
    assert with_odo > without and with_odo > 0.9, (without, with_odo)


def test_missing_odometry_rows_fall_back_to_the_speed_prior() -> None:
    truth = np.arange(100, 400)
    S = bumps(truth, noise=0.3, seed=7)
    odometry: list[float | None] = [1.0 if t % 2 else None for t in range(300)]
    got = filter_sequence(S, odometry=odometry)
    assert within(got.index[20:], truth[20:]).all()


@pytest.mark.parametrize(
    ("odometry", "message"),
    [([1.0, float("nan"), 1.0], "NaN"), ([1.0, 2.0], "expected 3"), ([1.0, float("inf"), 0.0], "NaN or infinity"),
     ([1.0, 1e7, 0.0], "exceeds"), (["a", 1.0, 1.0], "numbers"), (np.array([1.0, np.inf, 1.0]), "NaN or infinity")],
)  # fmt: skip
def test_bad_odometry_is_refused_naming_the_problem(odometry: object, message: str) -> None:
    with pytest.raises(InvalidInputError, match=message):
        check_odometry(odometry, 3)
    with pytest.raises(InvalidInputError, match=message):
        filter_sequence(np.zeros((3, 50)), odometry=odometry)


@settings(max_examples=30, deadline=None)
@given(st.floats(-30, 30), st.floats(0, 2), st.floats(0, 3))
def test_odometry_moves_the_belief_by_the_displacement(u: float, noise: float, floor: float) -> None:
    """One prediction step with odometry keeps the mass (away from the ends) and moves its mean
    by ``u``, with at least the stated variance."""
    n = 400
    cfg = SequenceConfig(odometry_noise=noise, odometry_floor=floor, relocalization=1e-12)
    filt = SequenceFilter(n, cfg)
    lik = np.full(n, 1e-20, dtype=np.float32)
    lik[200] = 1.0
    filt.update_likelihood(lik)
    filt.update_likelihood(np.ones(n, dtype=np.float32), u)
    post = filt.posterior
    mean = float(post @ np.arange(n))
    var = float(post @ (np.arange(n) - mean) ** 2)
    assert abs(mean - (200 + u)) < 0.05
    sigma = min(32.0, float(np.hypot(floor, noise * u)))
    f = u - np.floor(u)
    assert var >= 0.9 * max(sigma**2, f * (1 - f)) - 1e-6  # at least the stated noise …
    assert var <= 1.1 * max(sigma**2, f * (1 - f)) + 0.02  # … and not much more


def test_the_filter_restarts_instead_of_dividing_by_zero() -> None:
    """A prior that drives every state off the route with a vanishing jump probability."""
    cfg = SequenceConfig(min_speed=50, max_speed=50, relocalization=1e-45, reverse=False,
                         stop_probability=0.0, emission_scale=1e3)  # fmt: skip
    got = filter_sequence(bumps(np.arange(10, 60), n=100, seed=8), cfg)
    assert np.isfinite(got.confidence).all() and np.isfinite(got.speed).all()
    assert SequenceFilter(100, SequenceConfig(relocalization=1.0)).update(np.zeros(100)).index >= 0


def test_the_code_scorer_agrees_with_the_models_frame_scores() -> None:
    route = smooth_route(600, 32, seed=3)
    model = PhaseEncoder(trainer="prototype", code="residue", n_patterns=2, code_ratio=0.2).fit(
        route.reference
    )
    scorer = drive_scorer(model)
    assert isinstance(scorer, CodeScorer) and drive_scorer(model) is scorer
    S = model.frame_log_scores(route.query[:20])
    after = successors(route_sample(600), 600)
    for t, prep in enumerate(scorer.prepare_many(route.query[:20])):
        nxt = scorer.next_scores(prep)  # from the gathered rows: no class scores yet
        full = scorer.full(prep)
        np.testing.assert_allclose(nxt, full[after], atol=1e-9)
        np.testing.assert_allclose(scorer.next_scores(prep), full[after], atol=1e-9)
        offset = S[t] - full
        np.testing.assert_allclose(offset, offset[0], atol=1e-4)  # a constant per query
        idx = np.array([0, 5, 599, 300])
        np.testing.assert_allclose(scorer.frames(prep, idx), full[idx], atol=1e-9)
        assert scorer.best(prep) == int(np.argmax(S[t]))
        assert np.array_equal(scorer.sample_scores(prep), full[route_sample(600)])
    tracked = sequence_localize(model, route.query)
    whole = sequence_localize(model, route.query, SequenceConfig(tracking=False))
    assert (np.abs(tracked.index - whole.index) <= 2).mean() > 0.95


def test_the_code_scorers_route_sample_is_scored_once_per_query_from_its_own_rows() -> None:
    route = smooth_route(600, 32, seed=4)
    model = PhaseEncoder(trainer="prototype", code="residue", n_patterns=2, code_ratio=0.2).fit(
        route.reference
    )
    scorer = drive_scorer(model)
    assert isinstance(scorer, CodeScorer)
    sample = route_sample(600)
    for prep, again in zip(scorer.prepare_many(route.query[:10]),
                           scorer.prepare_many(route.query[:10]), strict=True):  # fmt: skip
        first = scorer.sample_scores(prep)  # before any full row: from the sample's own rows
        assert scorer.sample_scores(prep) is first and not first.flags.writeable
        np.testing.assert_allclose(first, scorer.frames(again, sample), atol=1e-9)
        np.testing.assert_allclose(first, scorer.full(again)[sample], atol=1e-4)


def test_a_vehicle_started_at_a_known_place_is_tracked_from_its_first_frame() -> None:
    truth = np.arange(900, 1300)
    S = bumps(truth, noise=0.8, seed=9)  # weak evidence: from nowhere it takes a while
    tracker = DriveTracker(MatrixScorer(S))
    tracker.start_at(900)
    assert tracker.mode == "windows"
    est = np.array([tracker.update(t).index for t in range(len(S))])
    assert within(est, truth).mean() > 0.97
    with pytest.raises(InvalidInputError, match="not on the route"):
        tracker.start_at(N)


def _kidnapped_on_a_long_route(
    budget: int, seed: int = 3
) -> tuple[DriveTracker, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A known start on a 20,000-frame route (``S·N`` state updates a whole-route frame, past
    the default budget), moved at t = 200; the tracker's estimates and modes, the truth and
    the frame scores."""
    truth = np.concatenate([np.arange(2000, 2200), np.arange(15000, 15300)])
    S = bumps(truth, n=20_000, noise=0.5, seed=seed)
    tracker = DriveTracker(MatrixScorer(S), SequenceConfig(whole_route_budget=budget))
    tracker.start_at(2000)
    est, modes = [], []
    for t in range(len(S)):
        est.append(tracker.update(t).index)
        modes.append(tracker.mode)
    return tracker, np.array(est), np.array(modes), truth, S


@pytest.mark.parametrize("budget", [65_536, 1])
def test_on_a_long_route_weak_evidence_widens_within_the_whole_route_budget(budget: int) -> None:
    tracker, est, modes, truth, _ = _kidnapped_on_a_long_route(budget)
    assert tracker.whole_cost == tracker.speeds.size * 20_000 > budget
    spent = (modes == "whole").sum() + tracker.relocalisations  # a visit: one frame's cost more
    assert spent * tracker.whole_cost <= len(est) * budget  # the credit bounds it
    if budget == 1:
        assert (modes == "whole").sum() == 0
    assert within(est[:200], truth[:200]).all()


def test_widened_windows_find_a_moved_vehicle_about_as_soon_as_the_whole_route() -> None:
    """Frames until a vehicle moved on a long route is found again and kept, over four drives
    (one drive's figure varies by ± 30 % with the noise): the tracker within the default budget
    against the whole route's filter."""
    tracked, whole = [], []
    for seed in (3, 4, 5, 6):
        _, est, _, truth, S = _kidnapped_on_a_long_route(65_536, seed)
        full = filter_sequence(S, SequenceConfig(tracking=False)).index
        tracked.append(_recovered_after(within(est[200:], truth[200:])))
        whole.append(_recovered_after(within(full[200:], truth[200:])))
    assert sum(tracked) <= 1.25 * sum(whole), (tracked, whole)
    assert all(t <= 1.5 * w for t, w in zip(tracked, whole, strict=True)), (tracked, whole)


def test_a_short_route_goes_back_to_the_whole_route_on_weak_evidence() -> None:
    truth = np.concatenate([np.arange(200, 400), np.arange(1500, 1700)])  # moved at t = 200
    tracker = DriveTracker(MatrixScorer(bumps(truth, noise=0.5, seed=3)))
    assert tracker.whole_cost <= SequenceConfig().whole_route_budget  # S·N affordable every frame
    modes = []
    for t in range(len(truth)):
        tracker.update(t)
        modes.append(tracker.mode)
    assert tracker.relocalisations >= 1 and "whole" in modes[200:]
    assert not tracker.wide or tracker.mode == "whole"  # widening is for long routes

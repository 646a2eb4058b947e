"""A fresh tracker (unknown start) on a route whose whole filter exceeds the budget starts in
widened windows at the first frame's candidates, not on the whole route (SYNTHETIC scores)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from service.encoding.drive_scoring import MatrixScorer
from service.encoding.sequence import SequenceConfig, filter_sequence
from service.encoding.tracking import DriveTracker
from service.encoding.tracking_windows import frames_outside, uniform_windows, windows_at

LONG = 20_000  # S·N = 320,000 state updates a whole-route frame: past the default budget
WIDE = 1_024  # window_frames: 10 windows of 97 frames, 16 × 970 = 15,520 <= LONG


def bumps(truth: np.ndarray, n: int, noise: float, seed: int) -> np.ndarray:
    frames = np.arange(n)[None, :]
    S = np.exp(-0.5 * ((frames - np.asarray(truth, float)[:, None]) / 3.0) ** 2)
    return S + np.random.default_rng(seed).normal(0.0, noise, S.shape)


def first_hit(ok: np.ndarray, run: int = 10) -> int:
    """First frame from which the estimate stays within ±5 frames for ``run`` frames."""
    for t in range(ok.size - run + 1):
        if ok[t : t + run].all():
            return t
    return ok.size


def _drive(budget: int, noise: float = 0.5, seed: int = 4) -> tuple[DriveTracker, np.ndarray,
                                                                   list[str], list[int], np.ndarray]:  # fmt: skip
    truth = np.arange(6_000, 6_400)
    S = bumps(truth, LONG, noise, seed)
    tracker = DriveTracker(MatrixScorer(S), SequenceConfig(whole_route_budget=budget, window_frames=WIDE))
    est, modes, windows = [], [], []
    for t in range(len(S)):
        est.append(tracker.update(t).index)
        modes.append(tracker.mode)
        windows.append(0 if tracker.P is None else tracker.P.shape[1])
    return tracker, np.array(est), modes, windows, truth


def test_before_its_first_frame_a_fresh_tracker_on_a_long_route_holds_nothing() -> None:
    tracker = DriveTracker(MatrixScorer(np.zeros((1, LONG))), SequenceConfig(window_frames=WIDE))
    assert tracker.mode == "windows" and tracker.nbytes == 0
    np.testing.assert_allclose(tracker.posterior, np.full(LONG, 1.0 / LONG))


@pytest.mark.parametrize("budget", [65_536, 1])
def test_a_fresh_tracker_on_a_long_route_starts_in_windows_within_the_budget(budget: int) -> None:
    tracker, est, modes, windows, truth = _drive(budget)
    assert tracker.whole_cost > budget
    assert modes[0] == "windows"  # the first frame already runs on windows
    assert max(windows) <= tracker.max_windows  # never more than window_frames of state
    whole = np.array(modes) == "whole"
    spent = whole.sum() + tracker.relocalisations  # a visit costs one frame more
    assert spent * tracker.whole_cost <= len(est) * budget  # the credit bounds it
    if budget == 1:
        assert not whole.any()
    ok = np.abs(est - truth) <= 5
    assert ok[-200:].mean() > 0.95
    S = bumps(truth, LONG, 0.5, 4)
    ref = filter_sequence(S, SequenceConfig(tracking=False))
    # found within a few global checks of when the whole route's filter finds it
    assert first_hit(ok) <= 1.5 * first_hit(np.abs(ref.index - truth) <= 5) + 30


def test_the_first_windows_are_at_the_first_frames_best_places() -> None:
    truth = np.arange(6_000, 6_010)
    S = bumps(truth, LONG, 0.05, 5)  # the true place stands out from the first frame
    tracker = DriveTracker(MatrixScorer(S), SequenceConfig(window_frames=WIDE))
    assert tracker.update(0).index == pytest.approx(6_000, abs=2)
    assert tracker.P is not None and tracker.lo[0] <= 6_000 < tracker.lo[0] + tracker.width
    assert tracker.wide and tracker.P.sum(dtype=np.float64) + tracker.outside == pytest.approx(1.0)


def test_where_the_widened_windows_would_hold_much_of_the_route_it_starts_on_the_whole() -> None:
    tracker = DriveTracker(MatrixScorer(np.zeros((1, LONG))))  # 21 windows: 2,037 frames
    assert tracker.whole_cost > SequenceConfig().whole_route_budget
    assert LONG < 16 * tracker.max_windows * tracker.width
    assert tracker.mode == "whole"


def test_a_fresh_tracker_on_a_short_route_still_starts_on_the_whole_route() -> None:
    n = 2_000
    tracker = DriveTracker(MatrixScorer(bumps(np.arange(500, 520), n, 0.3, 6)))
    assert tracker.whole_cost <= SequenceConfig().whole_route_budget
    assert tracker.mode == "whole"
    tracker.update(0)
    assert tracker.mode == "whole"


@settings(max_examples=60, deadline=None)
@given(st.lists(st.integers(0, 499), min_size=1, max_size=30), st.integers(1, 41),
       st.integers(1, 5))  # fmt: skip
def test_uniform_windows_hold_the_covered_frames_share_once(places: list[int], width: int,
                                                            speeds: int) -> None:  # fmt: skip
    n = 500
    lo = windows_at(np.array(places), width, n)
    assert lo.size >= 1 and ((lo >= 0) & (lo + width <= n)).all()
    first = int(np.clip(places[0] - width // 2, 0, n - width))
    assert lo[0] == first  # the best place's window comes first
    for c in places:  # every place lies in a window
        assert ((lo <= c) & (c < lo + width)).any()
    P = uniform_windows(lo, width, n, speeds)
    inside = float(P.sum(dtype=np.float64))
    outside = frames_outside(lo, width, n) / n
    assert inside + outside == pytest.approx(1.0, abs=1e-5)

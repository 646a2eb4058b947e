"""Where a tracker's windows lie: covered frames, frames outside, a posterior's best places."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from service.encoding.tracking_windows import (
    best_places,
    covered,
    frames_outside,
    recentre,
    windows_to_keep,
)


@settings(max_examples=60, deadline=None)
@given(st.integers(20, 400), st.integers(1, 15), st.lists(st.integers(0, 10_000), max_size=12))
def test_frames_outside_counts_the_union_of_the_windows(
    n: int, width: int, starts: list[int]
) -> None:
    lo = np.array([s % (n - width + 1) for s in starts], dtype=np.int64)
    mask = covered(lo, width, n)
    assert frames_outside(lo, width, n) == n - int(mask.sum())


@settings(max_examples=60, deadline=None)
@given(st.integers(50, 2_000), st.integers(1, 10), st.integers(1, 8), st.integers(0, 2**31))
def test_best_places_are_separate_windows_on_the_route_best_first(
    n: int, radius: int, most: int, seed: int
) -> None:
    width = 2 * radius + 1
    post = np.random.default_rng(seed).random(n)
    los = best_places(post, width, most)
    assert 1 <= los.size <= most and np.all((0 <= los) & (los <= n - width))
    best = int(post.argmax())
    assert abs(best - int(los[0]) - radius) <= radius  # the best frame is in the first window
    assert np.unique(los).size == los.size  # each place once
    if n >= 2 * most * width:  # room for them all: every block's best frame is a candidate
        assert los.size == most


def test_a_posterior_with_two_bumps_gets_a_window_at_each() -> None:
    post = np.full(10_000, 1e-9)
    post[2_000], post[7_000] = 0.6, 0.4
    los = best_places(post, 97, 4)
    assert los[0] == 2_000 - 48 and los[1] == 7_000 - 48


@settings(max_examples=100, deadline=None)
@given(n_frames=st.integers(40, 400), n_windows=st.integers(1, 4), seed=st.integers(0, 2**31 - 1))
def test_recentring_keeps_the_mass_and_the_windows_on_the_route(n_frames: int, n_windows: int,
                                                                seed: int) -> None:  # fmt: skip
    rng = np.random.default_rng(seed)
    radius = 5
    W = 2 * radius + 1
    P = rng.random((3, n_windows, W)).astype(np.float32)
    P /= 2 * P.sum()
    lo = rng.integers(0, n_frames - W + 1, size=n_windows).astype(np.int64)
    outside = 0.5
    before = float(P.sum(dtype=np.float64)) + outside
    peaks = P.sum(axis=0).argmax(axis=1)
    lo0 = lo.copy()
    after = recentre(P, lo, outside, radius, n_frames)
    assert ((lo >= 0) & (lo <= n_frames - W)).all()
    assert after >= 0.0
    if n_windows == 1 and n_frames >= 2 * W:  # no overlap, room outside: the mass is kept
        assert abs(float(P.sum(dtype=np.float64)) + after - before) < 1e-5
    for b in range(n_windows):  # a window whose peak stayed within radius // 2 did not move
        if abs(int(peaks[b]) - radius) <= radius // 2:
            assert lo[b] == lo0[b]


@settings(max_examples=100, deadline=None)
@given(masses=st.lists(st.floats(0.0, 1.0), min_size=1, max_size=12), most=st.integers(1, 12),
       level=st.floats(0.0, 1.0), seed=st.integers(0, 2**31 - 1))  # fmt: skip
def test_the_best_window_is_kept_and_at_most_most(masses: list[float], most: int, level: float,
                                                  seed: int) -> None:  # fmt: skip
    mass = np.array(masses)
    age = np.random.default_rng(seed).integers(0, 20, size=mass.size)
    keep = windows_to_keep(mass, age, level, 8, most)
    assert keep[mass == mass.max()].any()  # a heaviest window (any one of tied ones)
    assert 1 <= keep.sum() <= most
    expect = (mass > level) | (age < 8)
    expect[int(mass.argmax())] = True
    if expect.sum() <= most:  # within the limit: exactly the rule
        np.testing.assert_array_equal(keep, expect)

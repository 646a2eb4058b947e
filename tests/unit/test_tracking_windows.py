"""Where a tracker's windows lie: covered frames, frames outside, a posterior's best places."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from service.encoding.tracking_windows import best_places, covered, frames_outside


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

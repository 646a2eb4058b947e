"""Argmax and joint (beam search) decoding."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from service.encoding.decoding import decode, joint_decode, log_probabilities
from service.encoding.phases import index_to_labels


def random_logps(rng: np.random.Generator, periods: tuple[int, ...], n_q: int) -> list[np.ndarray]:
    return [log_probabilities(rng.standard_normal((n_q, p)) * 3) for p in periods]


@given(
    periods=st.lists(st.integers(2, 7), min_size=1, max_size=4).map(tuple),
    frac=st.floats(0.01, 1.0),
    beam=st.integers(1, 40),
    seed=st.integers(0, 2**31),
    mode=st.sampled_from(["joint", "argmax"]),
)
@settings(max_examples=200, deadline=None)
def test_decode_never_returns_an_index_outside_the_route(
    periods: tuple[int, ...], frac: float, beam: int, seed: int, mode: str
) -> None:
    n_valid = max(1, int(frac * math.prod(periods)))
    logps = random_logps(np.random.default_rng(seed), periods, 25)
    index, score = decode(logps, periods, n_valid, mode, beam)
    assert index.dtype == np.int64
    assert ((index >= 0) & (index < n_valid)).all()
    assert np.isfinite(score).all() and (score <= 1e-12).all()


@given(
    periods=st.lists(st.integers(2, 5), min_size=1, max_size=3).map(tuple),
    frac=st.floats(0.05, 1.0),
    seed=st.integers(0, 2**31),
)
@settings(max_examples=100, deadline=None)
def test_wide_beam_is_exact(periods: tuple[int, ...], frac: float, seed: int) -> None:
    n_valid = max(1, int(frac * math.prod(periods)))
    logps = random_logps(np.random.default_rng(seed), periods, 10)
    index, score = joint_decode(logps, periods, n_valid, beam_width=math.prod(periods))
    labels = index_to_labels(np.arange(n_valid), periods)
    brute = sum(lp[:, labels[:, j]] for j, lp in enumerate(logps))  # (q, n_valid)
    np.testing.assert_allclose(score, brute.max(axis=1))
    np.testing.assert_array_equal(brute[np.arange(10), index], brute.max(axis=1))


def test_argmax_decodes_each_digit_independently() -> None:
    periods = (3, 4)
    logps = [np.log(np.full((1, p), 0.01)) for p in periods]
    logps[0][0, 2] = 0.0
    logps[1][0, 1] = 0.0
    index, score = decode(logps, periods, 12, "argmax")
    assert index.tolist() == [2 * 4 + 1]
    assert score[0] == 0.0


def test_absent_classes_are_never_decoded() -> None:
    periods = (2, 3)
    lp = [log_probabilities(np.array([[5.0, -np.inf]])), log_probabilities(np.array([[0.0, 1.0, 2.0]]))]
    for mode in ("joint", "argmax"):
        index, _ = decode(lp, periods, 6, mode)
        assert index.tolist() == [2]


def test_confidence_is_the_product_of_digit_probabilities() -> None:
    p1 = np.array([[0.7, 0.3]])
    p2 = np.array([[0.1, 0.6, 0.3]])
    index, score = decode([np.log(p1), np.log(p2)], (2, 3), 6, "joint")
    assert index.tolist() == [1]
    assert math.isclose(math.exp(score[0]), 0.7 * 0.6)


def test_argmax_falls_back_to_joint_when_digits_point_past_the_route() -> None:
    periods = (2, 5)  # 10 codes, route of 7 frames
    lp1 = np.log(np.array([[0.2, 0.8]]))  # digit 1 → index ≥ 5
    lp2 = np.log(np.array([[0.05, 0.05, 0.1, 0.1, 0.7]]))  # digit 2 → 4: 1·5+4 = 9 ≥ 7
    index, _ = decode([lp1, lp2], periods, 7, "argmax")
    best = max(
        (i for i in range(7)),
        key=lambda i: lp1[0, i // 5] + lp2[0, i % 5],
    )
    assert index.tolist() == [best]
    assert index[0] < 7


@given(
    shape=st.tuples(st.integers(1, 5), st.integers(1, 3), st.integers(1, 40)),
    levels=st.integers(1, 6),
    seed=st.integers(0, 2**31),
    pad=st.booleans(),
)
@settings(max_examples=200, deadline=None)
def test_free_decode_finds_each_digits_top_two_as_a_sort_does(
    shape: tuple[int, int, int], levels: int, seed: int, pad: bool
) -> None:
    from service.encoding.exact_decode import free_decode

    rng = np.random.default_rng(seed)
    S = rng.integers(0, levels, shape).astype(np.float64)  # few levels: ties are common
    if pad and shape[2] > 1:
        S[:, :, rng.integers(1, shape[2]) :] = -np.inf  # padding beyond a digit's period
    free = free_decode(S)
    ordered = np.sort(S, axis=2)
    np.testing.assert_array_equal(free.top, ordered[:, :, -1])
    np.testing.assert_array_equal(free.digits, S.argmax(axis=2))
    second = ordered[:, :, -2] if shape[2] >= 2 else np.full(shape[:2], -np.inf)
    with np.errstate(invalid="ignore"):
        np.testing.assert_array_equal(free.gaps, ordered[:, :, -1] - second)

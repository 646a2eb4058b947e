"""Sequence filtering and per-frame scores on SYNTHETIC noisy routes."""

from __future__ import annotations

import numpy as np
import pytest

from service.encoding import ChunkedPlaceEncoder, PhaseEncoder
from service.encoding.sequence import SequenceConfig, SequenceFilter
from service.encoding.synthetic import smooth_route
from service.errors import InvalidParameterError


@pytest.fixture(scope="module")
def noisy():
    route = smooth_route(800, 48, query_noise=1.0, seed=5)  # SYNTHETIC, heavy query noise
    model = PhaseEncoder(trainer="ridge").fit(route.reference)
    return route, model


def test_frame_scores_agree_with_decoding(noisy) -> None:
    route, model = noisy
    scores = model.frame_log_scores(route.query[:50])
    loc = model.localize(route.query[:50])
    assert scores.shape == (50, 800)
    np.testing.assert_array_equal(scores.argmax(axis=1), loc.index)
    np.testing.assert_allclose(scores.max(axis=1), loc.log_score)


def test_chunked_frame_scores_agree_with_decoding() -> None:
    route = smooth_route(300, 32, seed=2)  # SYNTHETIC
    model = ChunkedPlaceEncoder(n_chunks=3, trainer="ridge", beam_width=10_000).fit(route.reference)
    scores = model.frame_log_scores(route.query)
    loc = model.localize(route.query)
    np.testing.assert_array_equal(scores.argmax(axis=1), loc.index)


def test_filter_raises_precision_on_a_forward_drive(noisy) -> None:
    route, model = noisy
    scores = model.frame_log_scores(route.query)
    truth = np.arange(800)
    single = np.mean(np.abs(scores.argmax(axis=1) - truth) <= 5)
    filt = SequenceFilter(800, SequenceConfig(window=6))
    est = np.array([filt.update(row).index for row in scores])
    filtered = np.mean(np.abs(est - truth) <= 5)
    assert filtered > single + 0.1, (single, filtered)


def test_window_of_one_is_the_single_frame_answer(noisy) -> None:
    route, model = noisy
    scores = model.frame_log_scores(route.query[:20])
    filt = SequenceFilter(800, SequenceConfig(window=1))
    for row in scores:
        est = filt.update(row)
        assert est.index == int(row.argmax()) and est.frames_used == 1
        assert 0 < est.confidence <= 1


def test_reset_and_bad_input(noisy) -> None:
    filt = SequenceFilter(800)
    filt.update(np.zeros(800))
    filt.reset()
    assert filt.update(np.zeros(800)).frames_used == 1
    with pytest.raises(InvalidParameterError):
        filt.update(np.zeros(10))
    with pytest.raises(InvalidParameterError):
        filt.update(np.full(800, -np.inf))
    with pytest.raises(InvalidParameterError):
        SequenceFilter(10, SequenceConfig(window=0))

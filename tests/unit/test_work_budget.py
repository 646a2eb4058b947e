"""The per-request work count and the cancellable drive (SYNTHETIC route)."""

from __future__ import annotations

import numpy as np
import pytest

from service.core.request_work import (
    BLOCK_WORK,
    Cancellation,
    cancellable,
    check_request,
    request_units,
)
from service.encoding import ModelParams, build_model
from service.encoding.sequence import SequenceConfig, sequence_localize
from service.encoding.synthetic import smooth_route
from service.errors import CancelledError, PayloadTooLargeError


def test_the_units_of_each_kind_of_request() -> None:
    assert request_units(10, 100) == 10 * 100 * 8  # a batch
    assert request_units(10, 100, states=7) == 10 * 100 * 15  # a drive
    assert request_units(2, 100, pixels=1000, images=2) == 2 * 100 * 8 + 3000 + 4_000_000
    check_request(0.0016, 100, 2)  # exactly the budget: accepted
    with pytest.raises(PayloadTooLargeError, match="GRIDPLACE_MAX_REQUEST_WORK=0.0016 million"):
        check_request(0.0016, 100, 3)


def test_a_cancellable_drive_answers_the_same_and_stops_between_blocks() -> None:
    route = smooth_route(400, 16, seed=2)  # SYNTHETIC
    model = build_model(ModelParams.parse()).fit(route.reference)
    config = SequenceConfig()
    plain = sequence_localize(model, route.query[:100], config)
    cancellation = Cancellation()
    wrapped, block = cancellable(model, cancellation, config.n_states, "a drive")
    assert block == min(256, BLOCK_WORK // (400 * config.n_states))
    again = sequence_localize(wrapped, route.query[:100], config, 10)
    assert np.array_equal(plain.index, again.index) and np.array_equal(plain.speed, again.speed)
    assert cancellation.frames_done == 100
    cancellation.cancel()
    with pytest.raises(CancelledError, match="the client went away; stopped after 100 frames"):
        sequence_localize(wrapped, route.query[:100], config, 10)
    assert cancellable(model, None, 7, "x") == (model, None)

"""Exact NN in the projected space (SYNTHETIC route): it is the brute-force nearest neighbour
of the front-end's rows, its frame scores agree with its answers, and its storage counts the
stored rows and the front-end."""

from __future__ import annotations

import numpy as np

from service.encoding.front_end import FrontEnd
from service.encoding.synthetic import smooth_route
from service.harness.projected_nn import ProjectedNN
from service.harness.quality_methods import PlacePooled, fit_places


def test_answers_are_the_brute_force_nearest_projected_row() -> None:
    route = smooth_route(200, 32, seed=4)
    model = ProjectedNN(n_components=8).fit(route.reference)
    front = FrontEnd.fit(np.asarray(route.reference, dtype=np.float64), True, 8, 0.75, "float32")
    R, Q = front.transform(route.reference), front.transform(route.query)
    expected = ((Q[:, None, :] - R[None, :, :]) ** 2).sum(axis=2).argmin(axis=1)
    loc = model.localize(route.query)
    assert np.mean(loc.index == expected) > 0.99  # float32 storage may flip exact ties
    assert np.array_equal(model.frame_log_scores(route.query).argmax(axis=1), loc.index)
    assert np.all((loc.confidence >= 0) & (loc.confidence <= 1))
    fp = model.footprint().to_dict()["components"]
    assert fp["reference"]["actual_bytes"] == 200 * 8 * 4 and "projection" in fp


def test_two_traversals_are_pooled_per_place() -> None:
    route = smooth_route(120, 16, seed=5)
    X = np.concatenate([route.reference, route.query])
    places = np.r_[np.arange(120), np.arange(120)]
    model = fit_places(ProjectedNN(n_components=8), X, places)
    assert isinstance(model, PlacePooled) and model.n_frames_ == 120
    assert model.frame_log_scores(route.query[:5]).shape == (5, 120)
    assert np.all(model.localize(route.query).index < 120)

"""Appearance adaptation: the running statistics, causality, streaming and edge cases."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from service.encoding import ModelParams, PhaseEncoder, build_model
from service.encoding.adaptation import (
    AdaptationConfig,
    AppearanceAdapter,
    adapt_drive,
    route_statistics,
)
from service.encoding.adaptation_step import MIN_SCALE_RATIO
from service.encoding.synthetic import smooth_route
from service.errors import InvalidParameterError

finite = st.floats(-100, 100, allow_nan=False, allow_infinity=False, width=32)


def _adapter(d: int, alpha: float, seed: int = 0, novelty: float = 0.0,
             robust: bool = True) -> AppearanceAdapter:  # fmt: skip
    """An adapter over random route statistics (``novelty=0``: every frame is learnt from;
    ``robust=False``: no clipping, no outlier, the plain exponentially weighted statistics)."""
    rng = np.random.default_rng(seed)
    plain = {} if robust else {"clip": 1e6, "outlier": 1e12}
    return AppearanceAdapter(rng.normal(size=d), rng.uniform(0.5, 2.0, size=d),
                             AdaptationConfig(alpha=alpha, novelty=novelty, **plain))  # fmt: skip


def _closed_form(a: AppearanceAdapter, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The adapted rows from the exponentially weighted sums written out in float64 (frame t
    sees the weighted mean and variance of the route's statistics, weight (1−α)^t, and frames
    < t), and the error float32 arithmetic may make in each: rounding of ``x − m`` (relative to
    ``|x| + |m|``) and of the result, in units of the standard deviation divided by."""
    alpha = a.config.alpha
    mu, sigma = a.route_mean.astype(np.float64), a.route_scale.astype(np.float64)
    out, tol = np.empty_like(X), np.empty_like(X)
    for t in range(X.shape[0]):
        w = alpha * (1 - alpha) ** np.arange(t - 1, -1, -1)  # weights of frames 0..t-1
        mean = (1 - alpha) ** t * mu + w @ X[:t]
        var = (1 - alpha) ** t * (sigma**2 + (mu - mean) ** 2) + w @ ((X[:t] - mean) ** 2)
        root = np.sqrt(np.maximum(var, (MIN_SCALE_RATIO * sigma) ** 2))
        out[t] = mu + sigma * (X[t] - mean) / root
        tol[t] = sigma * (1e-5 * (np.abs(X[:t + 1]).max(axis=0) + np.abs(mu)) / root
                          + 1e-5 * np.abs(out[t] - mu) / sigma + 1e-6)  # fmt: skip
    return out, tol


@settings(max_examples=40, deadline=None)
@given(
    X=arrays(np.float64, st.tuples(st.integers(2, 16), st.integers(1, 5)), elements=finite),
    cut=st.integers(0, 16),
)
def test_a_drive_adapted_in_pieces_equals_one_call(X: np.ndarray, cut: int) -> None:
    whole = _adapter(X.shape[1], 0.05).transform(X)
    a = _adapter(X.shape[1], 0.05)
    cut = min(cut, X.shape[0])
    pieces = np.vstack([a.transform(X[:cut]) if cut else np.empty((0, X.shape[1])), a.transform(X[cut:])])
    assert np.array_equal(whole, pieces)


@settings(max_examples=30, deadline=None)
@given(X=arrays(np.float64, st.tuples(st.integers(2, 10), st.integers(1, 5)), elements=finite))
def test_it_is_causal_and_starts_from_the_route(X: np.ndarray) -> None:
    """Frame t's answer depends on frames ≤ t only, and the first frame passes unchanged."""
    a = _adapter(X.shape[1], 0.1)
    got = a.transform(X)
    # float32: x − μ rounds relative to |x| + |μ|, so a value near 0 is off by about |μ|·1e-7
    assert np.allclose(got[0], X[0], rtol=1e-5, atol=1e-5 * (1 + np.abs(a.route_mean).max()))
    changed = X.copy()
    changed[-1] += 7.0
    again = _adapter(X.shape[1], 0.1).transform(changed)
    assert np.array_equal(again[:-1], got[:-1])


def test_a_drive_is_standardised_by_its_own_statistics() -> None:
    """A drive shifted and rescaled column by column ends up z-scored by the model as if it
    had the route's statistics: the model sees (x − m)/√v."""
    rng = np.random.default_rng(3)
    mu, sigma = np.array([0.0, 10.0]), np.array([1.0, 2.0])
    drive = rng.normal(size=(4000, 2)) * np.array([5.0, 0.1]) + np.array([50.0, -3.0])
    a = AppearanceAdapter(mu, sigma, AdaptationConfig(alpha=0.02, novelty=0.0))
    z = (a.transform(drive)[2000:] - mu) / sigma  # the model's z-score, once the drive is learnt
    assert np.allclose(z.mean(axis=0), 0.0, atol=0.15)
    assert np.allclose(z.std(axis=0), 1.0, atol=0.15)


def test_reset_forgets_the_drive_and_constant_columns_stay_finite() -> None:
    a = _adapter(3, 0.2)
    X = np.tile([[1.0, 5.0, -2.0]], (500, 1))  # a drive whose columns never change
    out = a.transform(X)
    assert np.isfinite(out).all()
    assert np.allclose(out[-1], a.route_mean, atol=1e-3)  # nothing left to stand out (float32)
    a.reset()
    assert a.learnt == 0
    assert a.frames == 0 and np.allclose(a.transform(X[:1]), X[:1])


@settings(max_examples=30, deadline=None)
@given(
    X=arrays(np.float64, st.tuples(st.integers(2, 12), st.integers(1, 5)), elements=finite),
    at=st.integers(0, 11),
    repeats=st.integers(1, 30),
)
def test_a_repeated_scene_does_not_move_the_statistics(X: np.ndarray, at: int, repeats: int) -> None:
    """A stopped vehicle: its frame sent again and again is answered the same way each time,
    and the drive after the stop is answered as if the stop had not happened (frames of any
    value: without the outlier rule, which a long stop on a far outlying scene would end)."""
    at = min(at, X.shape[0] - 1)
    stopped = np.vstack([X[: at + 1], np.repeat(X[at : at + 1], repeats, axis=0), X[at + 1 :]])
    plain = _adapter(X.shape[1], 0.2, novelty=1.0, robust=False).transform(X)
    a = _adapter(X.shape[1], 0.2, novelty=1.0, robust=False)
    got = a.transform(stopped)
    assert np.array_equal(got[: at + 1], plain[: at + 1])
    assert np.array_equal(got[at + 1 + repeats :], plain[at + 1 :])
    assert np.all(got[at + 1 : at + 1 + repeats] == got[at + 1])  # the stop answered alike
    assert a.frames == stopped.shape[0] and a.learnt <= X.shape[0]


def test_a_stop_in_a_normal_drive_does_not_move_the_robust_statistics() -> None:
    rng = np.random.default_rng(8)
    X = rng.normal(size=(300, 64)) * 1.5 + 0.5
    stopped = np.vstack([X[:150], np.repeat(X[149:150], 100, axis=0), X[150:]])
    plain = AppearanceAdapter(np.zeros(64), np.ones(64)).transform(X)
    got = AppearanceAdapter(np.zeros(64), np.ones(64)).transform(stopped)
    assert np.array_equal(got[250:], plain[150:])


def test_only_new_scenes_are_learnt_from() -> None:
    rng = np.random.default_rng(6)
    scenes = rng.normal(size=(40, 8))
    dense = np.repeat(scenes, 5, axis=0) + rng.normal(scale=0.01, size=(200, 8))  # 5 shots each
    a = AppearanceAdapter(np.zeros(8), np.ones(8))  # default novelty
    a.transform(dense)
    assert 30 <= a.learnt <= 40  # about one frame per scene (two unrelated ones differ by ≈ 2)
    every = AppearanceAdapter(np.zeros(8), np.ones(8), AdaptationConfig(novelty=0.0))
    every.transform(dense)
    assert every.learnt == 200


def test_a_wild_frame_is_answered_but_not_learnt_from() -> None:
    rng = np.random.default_rng(4)
    X = rng.normal(size=(20, 3))
    clean = _adapter(3, 0.1).transform(X)
    a = _adapter(3, 0.1)
    before = a.transform(X[:10])
    wild = a.transform(np.full((1, 3), 1e200))
    after = a.transform(X[10:])
    assert np.array_equal(before, clean[:10]) and np.array_equal(after, clean[10:])
    assert np.all(np.abs(wild) > 1e30)  # beyond float32: the model then refuses it (overflow)


def test_models_give_their_route_statistics() -> None:
    route = smooth_route(200, 16, seed=0)
    model = build_model(ModelParams()).fit(route.reference)
    stats = route_statistics(model)
    assert stats is not None
    assert np.allclose(stats.mean, route.reference.mean(axis=0), atol=1e-5)
    chunked = build_model(ModelParams(n_chunks=2)).fit(route.reference)
    assert route_statistics(chunked) is not None
    adapted = adapt_drive(model, route.query)
    assert adapted.shape == route.query.shape and np.allclose(adapted[0], route.query[0], atol=1e-5)
    bare = PhaseEncoder(n_patterns=2, normalize=False).fit(route.reference)
    with pytest.raises(InvalidParameterError, match="statistics"):
        AppearanceAdapter.for_model(bare)


def test_rows_of_another_width_are_refused() -> None:
    with pytest.raises(InvalidParameterError, match="d=3"):
        _adapter(3, 0.1).transform(np.zeros((2, 4)))
    with pytest.raises(InvalidParameterError):
        AppearanceAdapter(np.zeros(2), np.zeros(2))


def test_the_server_setting_defaults_to_the_library_default() -> None:
    from service.encoding.adaptation import DEFAULT_ALPHA, DEFAULT_NOVELTY
    from service.settings import Settings

    assert Settings().adaptation() == AdaptationConfig(alpha=DEFAULT_ALPHA, novelty=DEFAULT_NOVELTY)
    assert Settings().drive_adaptation

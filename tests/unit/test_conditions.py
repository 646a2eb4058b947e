"""Condition statistics: recorded at append/fit, persisted, named or inferred at query time."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from service.encoding import ModelParams, build_model
from service.encoding.adaptation import AdaptationConfig, AppearanceAdapter
from service.encoding.artifacts import load_model, save_model
from service.encoding.conditions import (
    MAX_CONDITIONS,
    REFERENCE,
    ConditionInference,
    ConditionSet,
    ConditionStats,
    UnknownConditionError,
    condition_key,
    condition_set,
    infer,
    record,
)
from service.errors import InvalidParameterError

D = 16


def _rows(seed: int, n: int, shift: float = 0.0, scale: float = 1.0) -> np.ndarray:
    return np.random.default_rng(seed).normal(shift, scale, size=(n, D))


def _set(shift: float = 3.0, scale: float = 0.5) -> ConditionSet:
    winter = ConditionStats.of(_rows(1, 400, shift, scale))
    return ConditionSet.build(np.zeros(D), np.ones(D), {"season=winter": winter})


@settings(max_examples=40, deadline=None)
@given(st.integers(1, 60), st.integers(1, 60), st.integers(0, 10_000))
def test_merged_statistics_are_those_of_all_rows(n1: int, n2: int, seed: int) -> None:
    a, b = _rows(seed, n1, 1.0, 2.0), _rows(seed + 1, n2, -1.0, 0.5)
    both = ConditionStats.of(np.concatenate([a, b]))
    merged = ConditionStats.of(a).merged(ConditionStats.of(b))
    assert merged.rows == n1 + n2
    np.testing.assert_allclose(merged.mean, both.mean, atol=1e-10)
    np.testing.assert_allclose(merged.var, both.var, atol=1e-9)
    np.testing.assert_allclose(both.var, np.concatenate([a, b]).var(axis=0), atol=1e-9)


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 10_000))
def test_log_likelihood_is_the_diagonal_gaussian(seed: int) -> None:
    cs = _set()
    X = _rows(seed, 5, 1.0)
    got = cs.log_likelihood(X)
    for c in range(len(cs)):
        m, v = cs.mean[c].astype(np.float64), cs.var[c].astype(np.float64)
        want = -0.5 * (((X - m) ** 2 / v).sum(axis=1) + np.log(v).sum())
        np.testing.assert_allclose(got[:, c], want, rtol=1e-5, atol=1e-4)


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 10_000))
def test_standardised_rows_score_as_their_own_condition(seed: int) -> None:
    """The route's z-score of a standardised row is the row's z-score in its condition."""
    rng = np.random.default_rng(seed)
    mu, sigma = rng.normal(size=D), rng.uniform(0.5, 2.0, size=D)
    cs = ConditionSet.build(mu, sigma, {"time=night": ConditionStats.of(_rows(seed, 50, 4.0, 3.0))})
    X = _rows(seed + 7, 3, 4.0, 3.0)
    Z = (cs.standardise(1, X, cs.mean[0], np.sqrt(cs.var[0])) - mu) / sigma
    np.testing.assert_allclose(Z, (X - cs.mean[1]) / np.sqrt(cs.var[1]), rtol=1e-4, atol=1e-4)
    assert cs.standardise(0, X, cs.mean[0], np.sqrt(cs.var[0])) is X  # the reference: as sent


def test_unknown_condition_names_the_known_ones() -> None:
    cs = _set()
    assert cs.names == (REFERENCE, "season=winter") and cs.index("season=winter") == 1
    with pytest.raises(UnknownConditionError, match="season=winter") as err:
        cs.index("season=summer")
    assert err.value.http_status == 400 and err.value.details["known"] == list(cs.names)


def test_record_merges_a_key_and_refuses_bad_keys_and_too_many() -> None:
    X = _rows(0, 10)
    once = record(None, "season=winter", X)
    twice = record(once, "season=winter", X)
    assert twice["season=winter"].rows == 20 and once["season=winter"].rows == 10
    assert record(once, None, X) == once
    for bad in ("winter", "=x", "a=b=c", ""):
        with pytest.raises(InvalidParameterError):
            record(None, bad, X)
    many = {f"k={i}": once["season=winter"] for i in range(MAX_CONDITIONS)}
    with pytest.raises(InvalidParameterError, match="conditions"):
        record(many, "k=new", X)
    assert condition_key({"time": "night", "season": "winter"}) == "season=winter,time=night"
    assert condition_key({}) is None


def test_inference_picks_the_drive_condition_and_then_keeps_it() -> None:
    cs = _set()
    winter, summer = _rows(5, 20, 3.0, 0.5), _rows(6, 20)
    assert infer(cs, winter) == 1 and infer(cs, summer) == 0
    vote = ConditionInference(cs, frames=4)
    assert vote.observe(winter[:4]) == 1 and vote.decided
    assert vote.observe(summer) == 1  # decided: later frames do not vote
    assert ConditionInference(cs, 4).observe(np.full((1, D), np.nan)) == 0  # no finite frame
    with pytest.raises(InvalidParameterError):
        ConditionInference(cs, 0)


def test_a_drive_started_from_a_condition_answers_its_first_frame_standardised() -> None:
    cs = _set()
    x = _rows(9, 1, 3.0, 0.5).astype(np.float32)
    named = AppearanceAdapter(np.zeros(D), np.ones(D)).start_from(cs, 1)
    static = cs.standardise(1, x, cs.mean[0], np.sqrt(cs.var[0]))
    np.testing.assert_allclose(named.transform(x), static, rtol=1e-5, atol=1e-5)
    assert named.condition_name == "season=winter" and not named.inferring
    inferred = AppearanceAdapter(np.zeros(D), np.ones(D)).start_from(cs, None, frames=3)
    np.testing.assert_allclose(inferred.transform(x), static, rtol=1e-5, atol=1e-5)
    assert inferred.condition_name == "season=winter" and inferred.inferring
    inferred.reset()  # a new drive infers again, from the reference
    assert inferred.condition_name == REFERENCE


@settings(max_examples=25, deadline=None)
@given(st.integers(0, 10_000), st.integers(1, 30))
def test_moving_to_a_condition_mid_drive_is_starting_from_it(seed: int, frames: int) -> None:
    """The running mean is linear in where it started: moving the start's remaining weight
    to another condition gives the mean of a drive started there (without clipping)."""
    cs = _set()
    config = AdaptationConfig(alpha=0.1, novelty=0.0, clip=1e6, outlier=1e12)
    X = _rows(seed, frames, 3.0, 0.5).astype(np.float32)
    moved = AppearanceAdapter(np.zeros(D), np.ones(D), config).start_from(cs, 0)
    moved.transform(X)
    moved.use_condition(1)
    started = AppearanceAdapter(np.zeros(D), np.ones(D), config).start_from(cs, 1)
    started.transform(X)
    np.testing.assert_allclose(moved._state[0], started._state[0], rtol=1e-4, atol=1e-4)
    assert moved.condition_name == started.condition_name == "season=winter"


def test_append_records_the_condition_and_the_artifact_keeps_it(tmp_path: Path) -> None:
    R, W = _rows(0, 60), _rows(1, 60, 2.0, 0.5)
    model = build_model(ModelParams()).fit(R)
    assert condition_set(model).names == (REFERENCE,)
    model.partial_fit(W[:30], condition="season=winter")
    model.partial_fit(W[30:], condition="season=winter")
    stats = model.conditions_["season=winter"]
    assert stats.rows == 60
    np.testing.assert_allclose(stats.mean, W.mean(axis=0), atol=1e-9)
    save_model(model, tmp_path / "m")
    loaded = load_model(tmp_path / "m")
    assert condition_set(loaded).names == (REFERENCE, "season=winter")
    np.testing.assert_allclose(loaded.conditions_["season=winter"].var, W.var(axis=0), atol=1e-9)
    assert condition_set(loaded) is condition_set(loaded)  # built once per recorded mapping
    with pytest.raises(InvalidParameterError):
        model.partial_fit(W[:5], condition="not a tag")
    assert model.conditions_["season=winter"].rows == 60  # a refused append changes nothing


def test_fit_records_one_condition_per_traversal() -> None:
    R, W = _rows(0, 40), _rows(1, 40, 2.0)
    model = build_model(ModelParams()).fit([R, W], conditions=[None, "season=winter"])
    assert list(model.conditions_) == ["season=winter"]
    np.testing.assert_allclose(model.conditions_["season=winter"].mean, W.mean(axis=0))
    with pytest.raises(InvalidParameterError, match="2 traversals need 2 conditions"):
        build_model(ModelParams()).fit([R, W], conditions=["season=winter"])

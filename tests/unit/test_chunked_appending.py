"""Appending traversals to a chunked prototype model (``ChunkedPlaceEncoder.partial_fit``):
the chunk classifier's and every chunk encoder's class means are the means of every row in
the fixed front-end. SYNTHETIC routes."""

from __future__ import annotations

import copy
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from service.encoding import ChunkedPlaceEncoder
from service.encoding.artifacts import load_model, save_model
from service.encoding.conditions import condition_set
from service.encoding.synthetic import smooth_route
from service.errors import InvalidInputError, InvalidParameterError, RetrainRequiredError

N, D = 80, 24


def _chunked(**kw: object) -> ChunkedPlaceEncoder:
    params: dict[str, object] = dict(n_chunks=2, trainer="prototype", code="residue", n_patterns=1,
                                     rho=1.0, n_components=12, dtype="float64", temperature=0.05)  # fmt: skip
    params.update(kw)
    return ChunkedPlaceEncoder(**params)  # type: ignore[arg-type]


@pytest.fixture(scope="module")
def route() -> tuple[np.ndarray, np.ndarray]:
    r = smooth_route(N, D, query_noise=0.4, seed=3)
    return r.reference.astype(np.float64), r.query.astype(np.float64)


def _unit(W: np.ndarray) -> np.ndarray:
    return W / np.linalg.norm(W, axis=1, keepdims=True)


def test_class_means_are_the_means_of_every_row(route) -> None:
    R, Q = route
    model = _chunked().fit(R)
    places = np.arange(20, 60)  # rows in both chunks
    model.partial_fit(Q[20:60], places=places)
    front = model.normalizer_
    Z = np.concatenate([front.transform(R), front.transform(Q[20:60])])
    labels = np.concatenate([np.arange(N), places])
    chunks = np.searchsorted(model.chunk_bounds_, labels, side="right") - 1
    clf = model.chunk_classifier_
    sums = np.zeros((2, clf.columns.size))
    np.add.at(sums, chunks, Z[:, clf.columns])
    np.testing.assert_allclose(clf.linear.dense[0], _unit(sums), atol=1e-12)
    np.testing.assert_array_equal(model.chunk_tally_.counts, np.bincount(chunks, minlength=2))
    for c, enc in enumerate(model.chunk_encoders_):
        s, e = model.chunk_bounds_[c], model.chunk_bounds_[c + 1]
        mine = (labels >= s) & (labels < e)
        np.testing.assert_array_equal(enc.tallies_[0].counts[: e - s].sum(), mine.sum())
    assert model.n_traversals_ == 2 and model.n_frames_ == N


@settings(max_examples=15, deadline=None)
@given(cut=st.integers(1, N - 1))
def test_appending_in_pieces_equals_appending_at_once(route, cut: int) -> None:
    R, Q = route
    base = _chunked().fit(R)
    once, pieces = copy.deepcopy(base), copy.deepcopy(base)
    once.partial_fit(Q)
    pieces.partial_fit(Q[:cut], places=np.arange(cut))
    pieces.partial_fit(Q[cut:], places=np.arange(cut, N))
    np.testing.assert_allclose(pieces.chunk_classifier_.linear.dense[0],
                               once.chunk_classifier_.linear.dense[0], atol=1e-10)  # fmt: skip
    for a, b in zip(pieces.chunk_encoders_, once.chunk_encoders_, strict=True):
        np.testing.assert_allclose(a.digits_[0].linear.dense[0], b.digits_[0].linear.dense[0],
                                   atol=1e-10)  # fmt: skip


def test_the_appended_traversal_localises_better(route) -> None:
    R, Q = route
    base = _chunked().fit(R)
    appended = copy.deepcopy(base)
    appended.partial_fit(Q[: N // 2], places=np.arange(N // 2), condition="season=winter")
    truth = np.arange(N // 2)
    assert np.mean(appended.predict(Q[: N // 2]) == truth) > np.mean(base.predict(Q[: N // 2]) == truth)
    assert condition_set(appended).names == ("reference", "season=winter")


def test_the_append_state_survives_the_artifact(route, tmp_path: Path) -> None:
    R, Q = route
    model = _chunked().fit(R)
    model.partial_fit(Q[:10], places=np.arange(10), condition="season=winter")
    save_model(model, tmp_path / "m")
    loaded = load_model(tmp_path / "m")
    assert isinstance(loaded, ChunkedPlaceEncoder)
    assert list(loaded.conditions_) == ["season=winter"]
    model.partial_fit(Q[10:], places=np.arange(10, N))
    loaded.partial_fit(Q[10:], places=np.arange(10, N))
    np.testing.assert_allclose(loaded.chunk_classifier_.linear.dense[0],
                               model.chunk_classifier_.linear.dense[0], atol=1e-12)  # fmt: skip
    np.testing.assert_array_equal(loaded.predict(Q), model.predict(Q))


def test_what_a_chunked_append_refuses(route) -> None:
    R, Q = route
    model = _chunked().fit(R)
    before = copy.deepcopy(model)
    with pytest.raises(RetrainRequiredError, match="chunk bounds"):
        model.partial_fit(Q[:3], places=np.array([N - 1, N, N + 1]), extend=True)
    with pytest.raises(InvalidInputError, match="beyond the route"):
        model.partial_fit(Q[:3], places=np.array([0, 1, N]))
    with pytest.raises(InvalidParameterError, match="whitening"):
        model.partial_fit(Q[:3], places=np.arange(3), whiten=True)
    np.testing.assert_array_equal(model.predict(Q), before.predict(Q))  # refused: unchanged
    with pytest.raises(InvalidParameterError, match="prototype"):
        _chunked(trainer="ridge").fit(R).partial_fit(Q[:3], places=np.arange(3))

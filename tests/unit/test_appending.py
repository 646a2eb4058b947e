"""Appending traversals to a fitted prototype model (``partial_fit``), unchunked and chunked
(the chunk classifier's and every chunk encoder's class means are the means of every row in
the fixed front-end). SYNTHETIC routes."""

from __future__ import annotations

import copy
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from service.encoding import ChunkedPlaceEncoder, ModelParams, PhaseEncoder, build_model
from service.encoding.artifacts import load_model, read_manifest, save_model
from service.encoding.conditions import condition_set
from service.encoding.synthetic import smooth_route
from service.errors import (
    DimensionMismatchError,
    InvalidInputError,
    InvalidParameterError,
    RetrainRequiredError,
)

N, D = 60, 24


def _proto(**kw: object) -> PhaseEncoder:
    params: dict[str, object] = dict(trainer="prototype", code="residue", n_patterns=1, rho=1.0,
                                     n_components=12, dtype="float64", temperature=0.05)  # fmt: skip
    params.update(kw)
    return PhaseEncoder(**params)  # type: ignore[arg-type]


@pytest.fixture(scope="module")
def route() -> tuple[np.ndarray, np.ndarray]:
    r = smooth_route(N, D, query_noise=0.4, seed=3)
    return r.reference.astype(np.float64), r.query.astype(np.float64)


def _unit(W: np.ndarray) -> np.ndarray:
    return W / np.linalg.norm(W, axis=1, keepdims=True)


def test_class_means_are_the_means_of_every_row_in_the_fixed_front_end(route) -> None:
    R, Q = route
    model = _proto().fit(R)
    front = model.normalizer_
    places = np.arange(10, 40)
    model.partial_fit(Q[10:40], places=places, whiten=False)
    Z = np.concatenate([front.transform(R), front.transform(Q[10:40])])
    labels = np.concatenate([np.arange(N), places])
    sums = np.zeros((N, Z.shape[1]))
    np.add.at(sums, labels, Z)
    W, b = model.digits_[0].linear.dense
    np.testing.assert_allclose(W, _unit(sums), atol=1e-12)
    assert np.all(b == 0) and model.n_traversals_ == 2 and model.n_frames_ == N
    np.testing.assert_array_equal(model.tallies_[0].counts, np.bincount(labels, minlength=N))


@settings(max_examples=25, deadline=None)
@given(cuts=st.lists(st.integers(1, N - 1), min_size=1, max_size=4, unique=True))
def test_appending_in_pieces_equals_appending_at_once(route, cuts: list[int]) -> None:
    R, Q = route
    base = _proto().fit(R)
    once = copy.deepcopy(base).partial_fit(Q, whiten=False)
    pieces = copy.deepcopy(base)
    bounds = [0, *sorted(cuts), N]
    for s, e in zip(bounds[:-1], bounds[1:], strict=True):
        pieces.partial_fit(Q[s:e], places=np.arange(s, e), whiten=False)
    np.testing.assert_allclose(pieces.digits_[0].linear.dense[0], once.digits_[0].linear.dense[0],
                               atol=1e-12)  # fmt: skip
    np.testing.assert_array_equal(pieces.tallies_[0].counts, once.tallies_[0].counts)


def test_untouched_int8_classes_stay_bit_identical(route) -> None:
    R, Q = route
    model = build_model(ModelParams()).fit(R)
    before = model.digits_[0].linear.weight.copy()
    model.partial_fit(Q[:20], whiten=False)
    after = model.digits_[0].linear.weight
    np.testing.assert_array_equal(after[20:], before[20:])
    assert not np.array_equal(after[:20], before[:20])


def test_extension_keeps_every_index_and_localises_the_new_places(route) -> None:
    R, Q = route
    model = _proto().fit(R[:40])
    before = model.digits_[0].linear.dense[0].copy()
    with pytest.raises(InvalidInputError, match="extend"):
        model.partial_fit(R[40:], places=np.arange(40, N))
    with pytest.raises(InvalidInputError, match="no row"):
        model.partial_fit(R[41:], places=np.arange(41, N), extend=True)
    model.partial_fit(R[40:], places=np.arange(40, N), extend=True, whiten=False)
    assert model.n_frames_ == N and model.periods_ == (N,)
    np.testing.assert_array_equal(model.digits_[0].linear.dense[0][:40], before)
    assert np.mean(np.abs(model.predict(Q) - np.arange(N)) <= 2) > 0.8
    assert model.predict(R[40:]).min() >= 40


def test_several_periods_extend_while_they_tell_the_places_apart(route) -> None:
    R, _ = route
    model = _proto(n_patterns=2, periods=(7, 9)).fit(R[:40])  # lcm 63
    labels = model.frame_labels_().copy()
    model.partial_fit(R[40:], places=np.arange(40, N), extend=True)
    assert model.periods_ == (7, 9)
    np.testing.assert_array_equal(model.frame_labels_()[:40], labels)
    small = _proto(n_patterns=2, periods=(5, 9)).fit(R[:40])  # lcm 45
    with pytest.raises(RetrainRequiredError, match="full retrain"):
        small.partial_fit(R[40:], places=np.arange(40, N), extend=True)


def test_bad_input_is_refused(route) -> None:
    R, Q = route
    model = _proto().fit(R)
    with pytest.raises(DimensionMismatchError, match="columns"):
        model.partial_fit(Q[:, :10])
    with pytest.raises(InvalidInputError, match="negative"):
        model.partial_fit(Q[:3], places=np.array([0, -1, 2]))
    with pytest.raises(InvalidInputError, match="entries"):
        model.partial_fit(Q[:3], places=np.array([0, 1]))
    with pytest.raises(InvalidParameterError, match="prototype"):
        PhaseEncoder(trainer="ridge").fit(R).partial_fit(Q)
    with pytest.raises(InvalidParameterError, match="whiten"):
        _proto(n_patterns=2, periods=(7, 9)).fit(R).partial_fit(Q, whiten=True)


def test_the_append_state_survives_the_artifact(route, tmp_path: Path) -> None:
    R, Q = route
    model = _proto(dtype="int8").fit(R)
    model.partial_fit(Q[:30])  # condition whitening: the state includes the scatter
    save_model(model, tmp_path / "m")
    assert set(read_manifest(tmp_path / "m")["files"]) == {"tensors.safetensors",
                                                         "append_state.safetensors"}  # fmt: skip
    loaded = load_model(tmp_path / "m")
    np.testing.assert_array_equal(loaded.predict(Q), model.predict(Q))
    model.partial_fit(Q[30:], places=np.arange(30, N))
    loaded.partial_fit(Q[30:], places=np.arange(30, N))
    np.testing.assert_array_equal(loaded.predict(Q), model.predict(Q))
    np.testing.assert_array_equal(loaded.digits_[0].linear.weight, model.digits_[0].linear.weight)


def test_condition_whitening_learns_a_shift_common_to_the_new_traversal(route) -> None:
    """A second condition shifts every frame along a few directions; appending half of its
    frames whitens those directions away, so the other half localises better."""
    R, _ = route
    rng = np.random.default_rng(1)
    shift = rng.standard_normal((3, D)) * 2.0
    other = R + rng.standard_normal((N, 3)) @ shift + 0.3 * rng.standard_normal(R.shape)
    base = _proto(n_components=20).fit(R)
    truth = np.arange(30, N)

    def precision(m: PhaseEncoder) -> float:
        return float(np.mean(np.abs(m.predict(other[30:]) - truth) <= 1))

    whitened = copy.deepcopy(base).partial_fit(other[:30], whiten=True)
    assert precision(whitened) > precision(base)


def test_an_inverted_file_is_refitted_over_the_moved_prototypes(route) -> None:
    R, Q = route
    model = _proto(search="ivf", nlist=4, nprobe=4).fit(R)  # every list probed: exact
    model.partial_fit(Q[:30])
    assert model.ivf_ is not None
    np.testing.assert_array_equal(model.localize(Q).index, model.localize(Q, search="flat").index)


def _chunked(**kw: object) -> ChunkedPlaceEncoder:
    params: dict[str, object] = dict(n_chunks=2, trainer="prototype", code="residue", n_patterns=1,
                                     rho=1.0, n_components=12, dtype="float64", temperature=0.05)  # fmt: skip
    params.update(kw)
    return ChunkedPlaceEncoder(**params)  # type: ignore[arg-type]


def test_chunked_class_means_are_the_means_of_every_row(route) -> None:
    R, Q = route
    model = _chunked().fit(R)
    places = np.arange(15, 45)  # rows in both chunks
    model.partial_fit(Q[15:45], places=places)
    front = model.normalizer_
    Z = np.concatenate([front.transform(R), front.transform(Q[15:45])])
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
def test_chunked_appending_in_pieces_equals_appending_at_once(route, cut: int) -> None:
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


def test_a_chunked_model_localises_the_appended_traversal_better(route) -> None:
    R, Q = route
    base = _chunked().fit(R)
    appended = copy.deepcopy(base)
    appended.partial_fit(Q[: N // 2], places=np.arange(N // 2), condition="season=winter")
    truth = np.arange(N // 2)
    assert np.mean(appended.predict(Q[: N // 2]) == truth) > np.mean(base.predict(Q[: N // 2]) == truth)
    assert condition_set(appended).names == ("reference", "season=winter")


def test_the_chunked_append_state_survives_the_artifact(route, tmp_path: Path) -> None:
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

"""Multi-traversal training: several traversals of the same places (SYNTHETIC routes)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from service.encoding import (
    ChunkedPlaceEncoder,
    PhaseEncoder,
    load_model,
    read_manifest,
    save_model,
)
from service.encoding.synthetic import SyntheticRoute
from service.encoding.traversals import as_traversals, chunk_rows
from service.errors import DimensionMismatchError, EmptyInputError, InvalidInputError


@given(
    n=st.integers(2, 30),
    extra=st.lists(st.integers(0, 10_000), max_size=40),
    seed=st.integers(0, 2**16),
)
@settings(max_examples=60, deadline=None)
def test_every_row_gets_its_place(n: int, extra: list[int], seed: int) -> None:
    rng = np.random.default_rng(seed)
    places = np.concatenate([np.arange(n), np.asarray(extra, dtype=np.int64) % n])
    rng.shuffle(places)
    half = places.shape[0] // 2
    X = rng.normal(size=(places.shape[0], 3))
    tr = as_traversals([X[:half], X[half:]], places=[places[:half], places[half:]])
    assert tr.n_places == n and tr.n_traversals == 2
    np.testing.assert_array_equal(tr.labels(), places)
    np.testing.assert_array_equal(tr.rows, X)
    bounds = np.array([0, n // 2, n])
    for c, rows in enumerate(chunk_rows(places, bounds)):
        assert ((places[rows] >= bounds[c]) & (places[rows] < bounds[c + 1])).all()
        assert rows.size == np.count_nonzero((places >= bounds[c]) & (places < bounds[c + 1]))


def test_frame_aligned_traversals_label_row_i_of_each_as_place_i() -> None:
    A, B = np.ones((5, 2)), np.zeros((5, 2))
    tr = as_traversals((A, B))
    assert (tr.n_places, tr.n_traversals) == (5, 2)
    np.testing.assert_array_equal(tr.labels(), np.tile(np.arange(5), 2))
    one = as_traversals(A)
    assert one.places is None and (one.n_places, one.n_traversals) == (5, 1)
    assert as_traversals([[1.0, 2.0], [3.0, 4.0]]).n_places == 2  # a list of rows is one array


@given(seed=st.integers(0, 2**16))
@settings(
    max_examples=8, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
def test_the_model_follows_places_not_row_order(seed: int, tiny_route: SyntheticRoute) -> None:
    rng = np.random.default_rng(seed)
    A, B = tiny_route.reference, tiny_route.query
    aligned = PhaseEncoder(trainer="ridge").fit([A, B])
    n = A.shape[0]
    perm = rng.permutation(2 * n)
    X, places = np.concatenate([A, B])[perm], np.tile(np.arange(n), 2)[perm]
    shuffled = PhaseEncoder(trainer="ridge").fit(X, places=places)
    assert shuffled.periods_ == aligned.periods_
    for a, b in zip(aligned.digits_, shuffled.digits_, strict=True):
        np.testing.assert_array_equal(a.columns, b.columns)
        np.testing.assert_allclose(
            np.asarray(a.linear.weight, dtype=np.float64),
            np.asarray(b.linear.weight, dtype=np.float64), rtol=1e-3, atol=1e-4,
        )  # fmt: skip
    np.testing.assert_array_equal(aligned.predict(A), shuffled.predict(A))


@given(seed=st.integers(0, 2**16))
@settings(
    max_examples=5, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
def test_chunks_follow_places_not_row_order(seed: int, tiny_route: SyntheticRoute) -> None:
    rng = np.random.default_rng(seed)
    A, B = tiny_route.reference, tiny_route.query
    n = A.shape[0]
    aligned = ChunkedPlaceEncoder(n_chunks=3, trainer="ridge").fit([A, B])
    perm = rng.permutation(2 * n)
    X, places = np.concatenate([A, B])[perm], np.tile(np.arange(n), 2)[perm]
    shuffled = ChunkedPlaceEncoder(n_chunks=3, trainer="ridge").fit(X, places=places)
    np.testing.assert_array_equal(aligned.chunk_bounds_, shuffled.chunk_bounds_)
    np.testing.assert_array_equal(aligned.chunk_classifier_.columns,
                                  shuffled.chunk_classifier_.columns)  # fmt: skip
    for a, b in zip(aligned.chunk_encoders_, shuffled.chunk_encoders_, strict=True):
        assert a.n_frames_ == b.n_frames_
        for da, db in zip(a.digits_, b.digits_, strict=True):
            np.testing.assert_array_equal(da.columns, db.columns)
    np.testing.assert_array_equal(aligned.predict(B), shuffled.predict(B))


def test_chunks_in_parallel_processes_train_the_same_model(tiny_route: SyntheticRoute) -> None:
    A, B = tiny_route.reference, tiny_route.query
    keep = np.arange(0, A.shape[0], 2)
    X, places = [A, B[keep]], [np.arange(A.shape[0]), keep]
    inline = ChunkedPlaceEncoder(n_chunks=2, trainer="ridge").fit(X, places=places)
    parallel = ChunkedPlaceEncoder(n_chunks=2, trainer="ridge", n_jobs=2).fit(X, places=places)
    np.testing.assert_array_equal(inline.predict(B), parallel.predict(B))
    assert parallel.n_traversals_ == 2


@pytest.mark.parametrize("chunks", [1, 3])
def test_two_identical_traversals_give_one_traversals_model(
    chunks: int, tiny_route: SyntheticRoute
) -> None:
    A = tiny_route.reference

    def model() -> PhaseEncoder | ChunkedPlaceEncoder:
        if chunks == 1:
            return PhaseEncoder(trainer="logreg")
        return ChunkedPlaceEncoder(n_chunks=chunks, trainer="logreg")

    one, two = model().fit(A), model().fit([A, A])
    assert (one.n_traversals_, two.n_traversals_) == (1, 2)
    assert one.n_frames_ == two.n_frames_ == A.shape[0]
    enc1 = [one] if chunks == 1 else one.chunk_encoders_  # type: ignore[union-attr]
    enc2 = [two] if chunks == 1 else two.chunk_encoders_  # type: ignore[union-attr]
    for e1, e2 in zip(enc1, enc2, strict=True):
        assert e1.periods_ == e2.periods_
        for a, b in zip(e1.digits_, e2.digits_, strict=True):
            np.testing.assert_array_equal(a.columns, b.columns)  # same pattern selection
    # the same statistics, the same places: every training frame is answered alike
    np.testing.assert_array_equal(one.predict(A), two.predict(A))


def test_a_second_traversal_helps_queries_like_it(small_route: SyntheticRoute) -> None:
    ref, query = small_route.reference, small_route.query
    half = query.shape[0] // 2
    # the second traversal is the query condition on the first half of the places only
    places = [np.arange(ref.shape[0]), np.arange(half)]
    model = PhaseEncoder(trainer="ridge").fit([ref, query[:half]], places=places)
    assert model.n_frames_ == ref.shape[0] and model.n_traversals_ == 2
    assert model.score(query[:half], tolerance=5) >= PhaseEncoder(trainer="ridge").fit(
        ref
    ).score(query[:half], tolerance=5)


@pytest.mark.parametrize("kind", ["phase", "chunked"])
def test_multi_traversal_fit_load_round_trip(
    kind: str, tiny_route: SyntheticRoute, tmp_path: Path
) -> None:
    A, B = tiny_route.reference, tiny_route.query
    n = A.shape[0]
    model = (
        PhaseEncoder(trainer="ridge") if kind == "phase"
        else ChunkedPlaceEncoder(n_chunks=3, trainer="ridge")
    )  # fmt: skip
    keep = np.arange(0, n, 2)  # the second traversal saw every other place
    model.fit([A, B[keep]], places=[np.arange(n), keep])
    manifest = save_model(model, tmp_path / "m")
    assert manifest["n_traversals"] == 2 and manifest["n_places"] == n
    assert read_manifest(tmp_path / "m")["n_traversals"] == 2
    loaded = load_model(tmp_path / "m")
    assert loaded.n_traversals_ == 2 and loaded.n_frames_ == n
    np.testing.assert_array_equal(loaded.predict(B), model.predict(B))


def test_one_traversal_models_record_one(tiny_route: SyntheticRoute, tmp_path: Path) -> None:
    model = PhaseEncoder(trainer="ridge").fit(tiny_route.reference)
    assert save_model(model, tmp_path / "m")["n_traversals"] == 1
    assert load_model(tmp_path / "m").n_traversals_ == 1


A5 = np.zeros((5, 4))
BAD_INPUT = [
    ("widths", [A5, np.zeros((5, 3))], None, DimensionMismatchError,
     "traversal 2 has 3 columns but traversal 1 has 4"),
    ("widths with places", [A5, np.zeros((2, 3))], [np.arange(5), np.arange(2)],
     DimensionMismatchError, "traversal 2 has 3 columns"),
    ("lengths", [A5, np.zeros((4, 4))], None, DimensionMismatchError,
     "traversal 2 has 4 rows but traversal 1 has 5"),
    ("index length", [A5, A5], [np.arange(5), np.arange(4)], DimensionMismatchError,
     "the place index of traversal 2 has 4 entries but its traversal has 5 rows"),
    ("too few indices", [A5, A5], [np.arange(5)], InvalidInputError,
     "2 traversals need 2 place-index arrays"),
    ("one index for several", [A5, A5], np.arange(10), InvalidInputError,
     "2 traversals need 2 place-index arrays"),
    ("negative", A5, np.array([0, 1, -2, 3, 4]), InvalidInputError,
     "negative place -2 at row 2"),
    ("uint64 beyond int64", A5, np.array([0, 1, 2, 3, 2**63], dtype=np.uint64),
     InvalidInputError, "place 9223372036854775808 at row 4, beyond any route"),
    ("missing place", A5, np.array([0, 1, 3, 3, 4]), InvalidInputError,
     "places 2 have no row"),
    ("place beyond rows", A5, np.array([0, 1, 2, 3, 9]), InvalidInputError,
     "names place 9 but there are only 5 rows"),
    ("float index", A5, np.arange(5.0), InvalidInputError, "must hold integers"),
    ("2-D index", A5, np.zeros((5, 1), dtype=np.int64), DimensionMismatchError,
     "must be a 1-D array"),
    ("one place", A5, np.zeros(5, dtype=np.int64), InvalidInputError, "at least 2 places"),
    ("no traversals", [], None, EmptyInputError, "no traversals"),
    ("several indices for one", A5, [np.arange(5), np.arange(5)], InvalidInputError,
     "2 place-index arrays given for one traversal"),
    ("nan in traversal 2", [A5, np.full((5, 4), np.nan)], None, InvalidInputError,
     "traversal 2 of the training descriptors: NaN"),
]  # fmt: skip


@pytest.mark.parametrize("case", BAD_INPUT, ids=[c[0] for c in BAD_INPUT])
@pytest.mark.parametrize("kind", ["phase", "chunked"])
def test_bad_traversals_are_refused_naming_the_problem(case: tuple, kind: str) -> None:
    _, X, places, error, message = case
    model = PhaseEncoder() if kind == "phase" else ChunkedPlaceEncoder(n_chunks=2)
    with pytest.raises(error, match=message):
        model.fit(X, places=places)

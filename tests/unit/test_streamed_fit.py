"""Streamed prototype fits: the class sums of a residue code accumulated over row blocks of
the route give the model of the in-memory fit (SYNTHETIC routes)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from service.encoding import streamed_fit
from service.encoding.encoder import PhaseEncoder
from service.encoding.factory import ModelParams, build_model
from service.encoding.synthetic import smooth_route


def _both(model_of, X: np.ndarray, monkeypatch: pytest.MonkeyPatch, rows: int):  # type: ignore[no-untyped-def]
    monkeypatch.setattr(streamed_fit, "STREAM_ROWS", rows)
    streamed = model_of().fit(X)
    with monkeypatch.context() as m:
        m.setattr(PhaseEncoder, "_class_prototypes", lambda self, *a: False)
        whole = model_of().fit(X)
    return streamed, whole


def _assert_same_model(a: PhaseEncoder, b: PhaseEncoder) -> None:
    assert a.periods_ == b.periods_ and len(a.digits_) == len(b.digits_) >= 2
    for da, db, ta, tb in zip(a.digits_, b.digits_, a.tallies_, b.tallies_, strict=True):
        np.testing.assert_array_equal(da.columns, db.columns)
        np.testing.assert_allclose(da.pattern.scores, db.pattern.scores, rtol=1e-9)
        Wa, ba = da.linear.dequantized()
        Wb, bb = db.linear.dequantized()
        np.testing.assert_allclose(Wa, Wb, rtol=1e-6, atol=1e-9)
        np.testing.assert_array_equal(ba, bb)
        np.testing.assert_array_equal(ta.counts, tb.counts)
        np.testing.assert_allclose(ta.mass, tb.mass, rtol=1e-9)


def test_the_drive_preset_streams_its_class_sums(monkeypatch: pytest.MonkeyPatch) -> None:
    route = smooth_route(3_000, 48, query_noise=0.4, seed=3)  # SYNTHETIC
    called: list[int] = []
    real = streamed_fit.class_sums_streamed
    monkeypatch.setattr(streamed_fit, "class_sums_streamed",
                        lambda *a, **k: called.append(1) or real(*a, **k))  # fmt: skip
    streamed, whole = _both(lambda: build_model(ModelParams(encoder_preset="drive")),
                            route.reference, monkeypatch, 701)  # fmt: skip
    assert called  # the streamed path ran, the other one did not
    _assert_same_model(streamed, whole)
    np.testing.assert_array_equal(streamed.localize(route.query).index,
                                  whole.localize(route.query).index)  # fmt: skip


@settings(max_examples=15, deadline=None)
@given(st.integers(50, 400), st.integers(7, 300), st.sampled_from([0.5, 1.0]),
       st.integers(0, 2**31 - 1))  # fmt: skip
def test_blocks_of_any_size_give_the_same_float64_model(
    n: int, rows: int, rho: float, seed: int
) -> None:
    X = np.random.default_rng(seed).normal(size=(n, 12))
    with pytest.MonkeyPatch.context() as mp:
        streamed, whole = _both(lambda: PhaseEncoder(
            code="residue", n_patterns=2, code_ratio=0.4, trainer="prototype", rho=rho,
            dtype="float64", n_components=6), X, mp, rows)  # fmt: skip
    _assert_same_model(streamed, whole)


def test_a_multi_traversal_fit_is_not_streamed(monkeypatch: pytest.MonkeyPatch) -> None:
    def refuse(*a: object, **k: object) -> None:
        raise AssertionError("streamed")

    monkeypatch.setattr(streamed_fit, "class_sums_streamed", refuse)
    X = np.random.default_rng(0).normal(size=(200, 8))
    model = PhaseEncoder(code="residue", n_patterns=2, code_ratio=0.4, trainer="prototype",
                         dtype="float64", n_components=4).fit([X, X + 0.1])  # fmt: skip
    assert model.n_traversals_ == 2

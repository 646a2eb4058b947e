"""Pattern learning: BCSS, Witten–Tibshirani sparse weights, column selection."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from service.encoding import PhaseEncoder
from service.encoding.patterns import bcss, learn_pattern, n_selected, sparse_weights
from service.errors import InvalidParameterError


def pairwise_bcss(X: np.ndarray, labels: np.ndarray) -> np.ndarray:
    """Witten & Tibshirani's pairwise definition, summed over ordered pairs."""
    n = X.shape[0]
    d = (X[:, None, :] - X[None, :, :]) ** 2  # (n, n, p)
    total = d.sum(axis=(0, 1)) / n
    within = np.zeros(X.shape[1])
    for c in np.unique(labels):
        m = labels == c
        within += d[np.ix_(m, m)].sum(axis=(0, 1)) / m.sum()
    return total - within


@given(
    X=arrays(np.float64, st.tuples(st.integers(2, 12), st.integers(1, 6)),
             elements=st.floats(-100, 100, allow_nan=False)),
    data=st.data(),
)
@settings(max_examples=150, deadline=None)
def test_bcss_equals_half_the_pairwise_formula(X: np.ndarray, data: st.DataObject) -> None:
    labels = np.asarray(data.draw(st.lists(st.integers(0, 3), min_size=X.shape[0],
                                           max_size=X.shape[0])))
    expected = 0.5 * pairwise_bcss(X, labels)
    np.testing.assert_allclose(bcss(X, labels), expected, rtol=1e-7, atol=1e-6)


@given(
    scores=arrays(np.float64, st.integers(1, 60), elements=st.floats(-10, 1e3, allow_nan=False)),
    gamma=st.floats(1.0, 10.0),
)
@settings(max_examples=200, deadline=None)
def test_sparse_weights_satisfy_both_norm_constraints(scores: np.ndarray, gamma: float) -> None:
    w = sparse_weights(scores, gamma)
    assert (w >= 0).all()
    if (scores > 0).any():
        assert np.linalg.norm(w) == pytest.approx(1.0, abs=1e-9)
        assert w.sum() <= gamma + 1e-6
        # Prop. 1: when the L1 bound binds, ||w||₁ = γ (unless several columns tie for the
        # top score, where soft-thresholding cannot separate them; a gap below the search's
        # resolution of Δ is a tie for it too)
        positive = np.maximum(scores, 0) / scores.max()  # scaled first: no underflow to 0
        unconstrained = positive / np.linalg.norm(positive)
        if unconstrained.sum() > gamma and np.count_nonzero(positive >= 1.0 - 1e-6) == 1:
            assert w.sum() == pytest.approx(gamma, abs=1e-5)
        # columns with non-positive scores never get weight
        assert (w[scores <= 0] == 0).all()
    else:
        assert (w == 0).all()


@pytest.mark.parametrize(("n_tied", "gamma", "kept"), [(10, 2.0, 4), (4, 1.5, 2), (3, 1.0, 1)])
def test_tied_top_scores_beyond_the_l1_bound_share_the_weight_without_warnings(
    n_tied: int, gamma: float, kept: int
) -> None:
    """√m > γ for m tied top scores: no threshold meets the bound (the search used to end
    dividing zero by zero); the weight goes evenly to the first ⌊γ²⌋ ties."""
    scores = np.concatenate([np.full(n_tied, 7.0), [1.0, 0.0, -2.0]])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        w = sparse_weights(scores, gamma)
    np.testing.assert_allclose(w[:kept], 1.0 / np.sqrt(kept))
    assert (w[kept:] == 0).all()
    assert np.linalg.norm(w) == pytest.approx(1.0) and w.sum() <= gamma + 1e-12


def test_a_near_tie_below_the_search_tolerance_keeps_the_top_column() -> None:
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        w = sparse_weights(np.array([1.0, 1.0 - 1e-12, 0.5]), 1.0)
    np.testing.assert_array_equal(w, [1.0, 0.0, 0.0])


def test_identical_columns_train_an_encoder_without_warnings() -> None:
    """Every column the same (a blank or saturated camera): all BCSS scores tie."""
    rng = np.random.default_rng(0)
    X = np.repeat(np.cumsum(rng.standard_normal((120, 1)), axis=0), 16, axis=1)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        pattern = learn_pattern(X, np.arange(120) % 6, rho=0.5)
        model = PhaseEncoder(rho=0.5, trainer="ridge").fit(X)
        pred = model.predict(X)
    np.testing.assert_array_equal(pattern.columns, np.arange(8))  # ties: lowest indices
    assert pred.shape == (120,)


def test_sparse_weights_are_monotone_in_the_score() -> None:
    rng = np.random.default_rng(0)
    a = rng.random(50)
    w = sparse_weights(a, 3.0)
    order = np.argsort(a)
    assert np.all(np.diff(w[order]) >= -1e-12)
    assert (w == 0).sum() > 0  # γ = 3 forces sparsity on 50 columns


def test_learn_pattern_keeps_the_informative_columns() -> None:
    rng = np.random.default_rng(1)
    labels = np.repeat(np.arange(4), 50)
    X = rng.standard_normal((200, 20))
    X[:, [3, 11, 17]] += 3.0 * labels[:, None]  # only these columns carry the digit
    sel = learn_pattern(X, labels, rho=0.15)
    assert sel.columns.tolist() == [3, 11, 17]
    assert sel.weights.shape == (20,)
    assert np.all(np.diff(sel.columns) > 0)


def test_selection_is_stable_with_ties_broken_by_column_index() -> None:
    X = np.zeros((6, 5))
    labels = np.array([0, 0, 0, 1, 1, 1])  # every column constant: all scores tie at 0
    assert learn_pattern(X, labels, rho=0.4).columns.tolist() == [0, 1]


@pytest.mark.parametrize("rho", [0.0, -0.1, 1.5, float("nan")])
def test_rho_outside_unit_interval_is_rejected(rho: float) -> None:
    with pytest.raises(InvalidParameterError):
        n_selected(10, rho)


def test_gamma_below_one_is_rejected() -> None:
    with pytest.raises(InvalidParameterError):
        sparse_weights(np.ones(4), 0.5)

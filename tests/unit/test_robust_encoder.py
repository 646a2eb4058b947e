"""The condition-robust pieces: projection front-end, prototype trainer, residue code,
temperature calibration and presets. All routes here are SYNTHETIC."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from safetensors.numpy import load_file
from sklearn.base import clone

from service.encoding import ChunkedPlaceEncoder, ModelParams, PhaseEncoder, build_model
from service.encoding.artifacts import TENSORS, load_model, save_model
from service.encoding.calibration import calibrate, log_likelihood
from service.encoding.front_end import FrontEnd
from service.encoding.presets import DEFAULT_PRESET, PRESETS
from service.encoding.projection import Projection
from service.encoding.prototype import DEFAULT_TEMPERATURE
from service.encoding.residue import (
    alias_gap,
    residue_labels,
    residue_periods,
    validate_residue_periods,
)
from service.encoding.synthetic import smooth_route
from service.encoding.trainers import TRAINERS, train_linear
from service.errors import InvalidParameterError


def _rows(n: int, d: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return rng.standard_normal((n, d)) * np.linspace(3.0, 0.2, d)  # distinct variances


# -- projection ---------------------------------------------------------------------------
@given(n=st.integers(8, 60), d=st.integers(2, 24), m=st.integers(1, 30),
       power=st.sampled_from([0.0, 0.5, 0.75, 1.0]), seed=st.integers(0, 2**16))  # fmt: skip
@settings(max_examples=40, deadline=None)
def test_projection_axes_are_orthogonal_and_whitened(
    n: int, d: int, m: int, power: float, seed: int
) -> None:
    X = _rows(n, d, seed)
    proj = Projection.fit(X, m, power, dtype="float64")
    W, b = proj.linear.dense
    assert proj.n_components == min(m, d, n - 1) or proj.n_components <= min(m, d, n)
    cov = np.cov(X, rowvar=False, bias=True)
    evals = np.sort(np.linalg.eigvalsh(cov))[::-1][: proj.n_components]
    # rows of W are the principal axes scaled by λ^(−power/2): W C Wᵀ = diag(λ^(1−power))
    np.testing.assert_allclose(W @ cov @ W.T, np.diag(evals ** (1.0 - power)),
                               atol=1e-8 * max(1.0, evals[0]))  # fmt: skip
    np.testing.assert_allclose(b, -(X.mean(axis=0) @ W.T), atol=1e-9)
    Z = proj.transform(X)
    np.testing.assert_allclose(np.linalg.norm(Z, axis=1), 1.0, rtol=1e-12)


@given(n=st.integers(20, 60), d=st.integers(2, 12), seed=st.integers(0, 2**16))
@settings(max_examples=25, deadline=None)
def test_full_pca_without_whitening_round_trips(n: int, d: int, seed: int) -> None:
    """Power 0 with every component is a rotation: the rows come back from their projection
    (before the unit norm) and the Gram path (n < d) agrees with the covariance path."""
    X = _rows(n, d, seed)
    proj = Projection.fit(X, d, 0.0, dtype="float64")
    W, b = proj.linear.dense
    Z = X @ W.T + b
    np.testing.assert_allclose(Z @ W + X.mean(axis=0), X, atol=1e-8)
    wide = Projection.fit(X[: d - 1] if d > 2 else X, d, 0.0, dtype="float64")
    assert wide.n_components <= d


def test_front_end_round_trips_bit_identically() -> None:
    X = _rows(200, 40, 1)
    for dtype in ("float64", "float32", "float16", "int8"):
        front = FrontEnd.fit(X.astype(np.float32), True, 16, 0.75, dtype)
        back = FrontEnd.from_arrays(front.to_arrays("norm"), "norm")
        assert back is not None and back.n_outputs == 16 and back.n_features == 40
        np.testing.assert_array_equal(back.transform(X), front.transform(X))
    assert FrontEnd.from_arrays({}, "norm") is None


# -- prototype trainer ---------------------------------------------------------------------
@given(n=st.integers(4, 60), d=st.integers(1, 10), classes=st.integers(2, 8),
       seed=st.integers(0, 2**16))  # fmt: skip
@settings(max_examples=40, deadline=None)
def test_prototype_is_the_normalised_class_mean(n: int, d: int, classes: int, seed: int) -> None:
    rng = np.random.default_rng(seed)
    X = rng.standard_normal((n, d))
    y = rng.integers(0, classes, n)
    W, b = train_linear(X, y, classes, "prototype")
    for c in range(classes):
        if not (y == c).any():
            assert b[c] == -np.inf and not W[c].any()  # never decoded
            continue
        mean = X[y == c].mean(axis=0)
        if np.unique(y).size == 1:
            continue  # one class present: the digit carries no information
        np.testing.assert_allclose(W[c], mean / np.linalg.norm(mean), rtol=1e-9, atol=1e-12)
        assert b[c] == 0.0
    assert "prototype" in TRAINERS


# -- residue code ----------------------------------------------------------------------------
@given(n=st.integers(2, 5000), k=st.integers(1, 6), ratio=st.sampled_from([0.25, 0.5, 1.0, 2.0]))
@settings(max_examples=60, deadline=None)
def test_residue_periods_are_distinct_cover_the_route_and_sum_near_ratio_n(
    n: int, k: int, ratio: float
) -> None:
    if k > math.ceil(math.log2(n)):
        with pytest.raises(InvalidParameterError, match="too many"):
            residue_periods(n, k, ratio)
        return
    periods = residue_periods(n, k, ratio)
    assert len(periods) == k and len(set(periods)) == k and min(periods) >= 2
    assert math.lcm(*periods) >= n
    assert validate_residue_periods(periods, n) == periods
    assert residue_periods(n, k, ratio) == periods  # deterministic
    if k > 1 and ratio * n >= 40 * k * k:
        assert abs(sum(periods) - ratio * n) <= 0.02 * ratio * n + k


def test_residue_periods_keep_aliases_apart() -> None:
    n = 3576
    periods = residue_periods(n, 4, 1.0)
    near_equal = (891, 893, 895, 897)
    assert alias_gap(periods, n) > 10 * alias_gap(near_equal, n)


def test_residue_labels_and_their_validation() -> None:
    table = residue_labels(10, (3, 4))
    np.testing.assert_array_equal(table[:, 0], np.arange(10) % 3)
    np.testing.assert_array_equal(table[:, 1], np.arange(10) % 4)
    with pytest.raises(InvalidParameterError, match="pairwise distinct"):
        validate_residue_periods((5, 5), 10)
    with pytest.raises(InvalidParameterError, match="fewer than"):
        validate_residue_periods((2, 4), 10)  # lcm 4 < 10
    assert validate_residue_periods((4, 6), 12) == (4, 6)  # co-prime is not required


@given(seed=st.integers(0, 2**16), n=st.integers(30, 300), k=st.integers(2, 4),
       trainer=st.sampled_from(["prototype", "ridge"]))  # fmt: skip
@settings(max_examples=15, deadline=None)
def test_a_noiseless_route_is_decoded_exactly(seed: int, n: int, k: int, trainer: str) -> None:
    X = np.random.default_rng(seed).standard_normal((n, 96))  # well separated frames
    model = PhaseEncoder(code="residue", n_patterns=k, rho=1.0, trainer=trainer).fit(X)
    np.testing.assert_array_equal(model.predict(X), np.arange(n))
    assert model.frame_labels_().shape == (n, k)


# -- calibration ------------------------------------------------------------------------------
def test_calibration_fits_on_the_validation_split_only(tmp_path: Path) -> None:
    route = smooth_route(300, 32, seed=4)
    model = build_model(ModelParams()).fit(route.reference)
    assert model.digits_[0].temperature == PRESETS[DEFAULT_PRESET].temperature
    val, test = np.arange(0, 300, 2), np.arange(1, 300, 2)
    Q = route.query.astype(np.float64).copy()
    Q_val, truth_val = Q[val].copy(), val.copy()
    Q[test] = np.nan  # the test rows cannot be what the calibration reads
    before = log_likelihood(model, Q_val, truth_val)
    T = calibrate(model, Q_val, truth_val)
    assert 1e-4 <= T <= 1e2 and model.temperature == T
    assert all(dc.temperature == T for dc in model.digits_)
    assert log_likelihood(model, Q_val, truth_val) >= before - 1e-9
    save_model(model, tmp_path / "m")
    back = load_model(tmp_path / "m")
    assert all(dc.temperature == T for dc in back.digits_)  # type: ignore[attr-defined]
    q = route.query[test[:20]]
    np.testing.assert_array_equal(back.frame_log_scores(q), model.frame_log_scores(q))  # type: ignore[attr-defined]
    with pytest.raises(InvalidParameterError, match="true frames"):
        calibrate(model, Q_val, truth_val[:-1])


def test_calibrating_a_chunked_model_sets_every_classifier() -> None:
    route = smooth_route(400, 24, seed=6)
    model = build_model(ModelParams(n_chunks=2, n_components=12)).fit(route.reference)
    T = calibrate(model, route.query[::3], np.arange(0, 400, 3))
    assert model.chunk_classifier_.temperature == T  # type: ignore[union-attr]
    assert all(dc.temperature == T for e in model.chunk_encoders_ for dc in e.digits_)  # type: ignore[union-attr]


# -- presets, artifacts, footprint ----------------------------------------------------------------
def test_the_default_is_the_robust_preset() -> None:
    assert DEFAULT_PRESET == "robust"
    params = ModelParams()
    for key, value in PRESETS["robust"].params().items():
        assert getattr(params, key) == value
    assert ModelParams(encoder_preset="robust") == params.model_copy(update={"encoder_preset": "robust"})
    with pytest.raises(InvalidParameterError, match="encoder_preset"):
        ModelParams.parse(encoder_preset="fancy")
    assert ModelParams(trainer="ridge").temperature is None  # robust's T is the prototype's
    assert ModelParams(trainer="ridge", temperature=2.0).temperature == 2.0


@pytest.mark.parametrize("name", sorted(PRESETS))
@pytest.mark.parametrize("n_chunks", [1, 3])
def test_every_preset_saves_and_loads_bit_identically(name: str, n_chunks: int, tmp_path: Path) -> None:
    route = smooth_route(240, 24, seed=2)
    params = ModelParams(encoder_preset=name, n_chunks=n_chunks,  # type: ignore[arg-type]
                         **({"n_components": 16} if PRESETS[name].n_components else {}))  # fmt: skip
    model = build_model(params).fit(route.reference)
    manifest = save_model(model, tmp_path / "m")
    back = load_model(tmp_path / "m")
    assert type(back) is type(model) and back.get_params() == model.get_params()
    loc, loc2 = model.localize(route.query), back.localize(route.query)
    np.testing.assert_array_equal(loc.index, loc2.index)
    np.testing.assert_array_equal(loc.log_score, loc2.log_score)
    np.testing.assert_array_equal(model.frame_log_scores(route.query[:10]),  # type: ignore[attr-defined]
                                  back.frame_log_scores(route.query[:10]))  # type: ignore[attr-defined]
    tensors = load_file(str(tmp_path / "m" / TENSORS))
    assert manifest["footprint"]["actual_bytes"] == sum(v.nbytes for v in tensors.values())
    save_model(back, tmp_path / "again")
    again = load_file(str(tmp_path / "again" / TENSORS))
    assert again.keys() == tensors.keys()
    for key in tensors:
        np.testing.assert_array_equal(again[key], tensors[key])


def test_footprint_counts_the_projection() -> None:
    route = smooth_route(300, 40, seed=3)
    model = PhaseEncoder(code="residue", n_patterns=4, rho=1.0, trainer="prototype",
                         n_components=16, dtype="int8").fit(route.reference)  # fmt: skip
    fp = model.footprint()
    proj = fp.components["projection"]
    assert proj.paper_bytes == 8.0 * (40 + 1) * 16
    assert proj.actual_bytes == 16 * 40 + 4 * 16 + 4 * 16  # int8 + float32 bias + scale
    assert fp.components["encoders"].actual_bytes == (16 + 8) * sum(model.periods_) + 8 * 4
    assert fp.components["masks"].paper_bytes == 4 * 16 / 8  # masks over projected columns
    assert model.n_features_in_ == 40 and all(dc.columns.max() < 16 for dc in model.digits_)


def test_a_prototype_without_a_temperature_takes_the_trainers_default() -> None:
    route = smooth_route(120, 16, seed=5)
    model = PhaseEncoder(code="residue", trainer="prototype").fit(route.reference)
    assert all(dc.temperature == DEFAULT_TEMPERATURE for dc in model.digits_)
    assert PhaseEncoder(trainer="ridge").fit(route.reference).digits_[0].temperature == 1.0


def test_one_residue_digit_is_a_softmax_over_the_frames() -> None:
    """The robust preset's k = 1: one class per frame, its prototype the frame's own
    projected row, so the answer is the cosine nearest neighbour in the projected space."""
    route = smooth_route(300, 32, seed=8)
    model = build_model(ModelParams()).fit(route.reference)
    assert model.periods_ == (300,)  # type: ignore[union-attr]
    front = model.normalizer_  # type: ignore[union-attr]
    R, Q = front.transform(route.reference), front.transform(route.query)
    W, _ = model.digits_[0].linear.dense  # type: ignore[union-attr]
    np.testing.assert_array_equal(model.predict(route.query), (Q @ W.T).argmax(axis=1))
    assert (np.abs(R @ W.T).argmax(axis=1) == np.arange(300)).mean() > 0.99  # int8 rounding


def test_sklearn_contract_with_the_new_parameters() -> None:
    model = PhaseEncoder(code="residue", code_ratio=0.5, n_components=8, whiten_power=0.5,
                         temperature=0.1, trainer="prototype")  # fmt: skip
    twin = clone(model)
    assert twin.get_params() == model.get_params()
    chunked = clone(ChunkedPlaceEncoder(n_chunks=2, code="residue", n_components=8))
    assert chunked.get_params()["n_components"] == 8
    route = smooth_route(200, 16, seed=1)
    twin.fit(route.reference)
    assert twin.normalizer_.n_outputs == 8 and sum(twin.periods_) <= 0.5 * 200 + 8


def test_a_residue_route_refuses_impossible_periods_before_training() -> None:
    from service.encoding import check_route

    with pytest.raises(InvalidParameterError, match="pairwise distinct"):
        check_route(ModelParams(periods=(5, 5), code="residue"), 20, 8)
    assert ModelParams(periods=(5, 5)).code == "mixed_radix"  # explicit periods: as always
    check_route(ModelParams(), 20, 8)
    check_route(ModelParams(n_chunks=4), 4000, 8)

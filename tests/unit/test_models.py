"""The estimators end to end on SYNTHETIC smooth routes."""

from __future__ import annotations

import numpy as np
import pytest
from sklearn.base import clone

from service.encoding import (
    ChunkedPlaceEncoder,
    ExactNN,
    ModelParams,
    PhaseEncoder,
    RhythmicEncoder,
    build_model,
)
from service.encoding.baselines import coprime_periods, crt
from service.encoding.synthetic import SyntheticRoute
from service.encoding.trainers import TRAINERS, train_linear


@pytest.mark.parametrize("trainer", TRAINERS)
def test_every_trainer_produces_the_same_weight_arrays(trainer: str, small_route: SyntheticRoute) -> None:
    X = small_route.reference[:, :16].astype(np.float64)
    y = np.arange(X.shape[0]) % 5
    W, b = train_linear(X, y, 6, trainer)  # class 5 never occurs
    assert W.shape == (6, 16) and b.shape == (6,)
    assert W.dtype == np.float64 and b.dtype == np.float64
    assert np.isneginf(b[5]) and not W[5].any()
    assert np.isfinite(W[:5]).all() and np.isfinite(b[:5]).all()
    acc = np.mean((X @ W.T + b).argmax(axis=1) == y)
    assert acc > 0.2  # better than the 1/5 of guessing on the training rows


@pytest.mark.parametrize("trainer", TRAINERS)
@pytest.mark.parametrize("decode", ["joint", "argmax"])
def test_phase_encoder_localizes_a_smooth_route(
    trainer: str, decode: str, small_route: SyntheticRoute
) -> None:
    model = PhaseEncoder(n_patterns=2, rho=0.5, trainer=trainer, decode=decode)
    model.fit(small_route.reference)
    n = small_route.query.shape[0]
    p5 = model.score(small_route.query, tolerance=5)
    chance = 11 / n
    assert p5 > 20 * chance, f"precision@5 {p5:.3f} vs chance {chance:.3f}"
    loc = model.localize(small_route.query)
    assert ((loc.index >= 0) & (loc.index < n)).all()
    assert ((loc.confidence > 0) & (loc.confidence <= 1)).all()
    # confidence ranks answers: the most confident half is at least as precise
    confident = loc.confidence >= np.median(loc.confidence)
    correct = np.abs(loc.index - np.arange(n)) <= 5
    assert correct[confident].mean() >= correct.mean() - 0.02


def test_chunked_encoder_localizes_a_smooth_route(small_route: SyntheticRoute) -> None:
    progress: list[tuple[str, int, int]] = []
    model = ChunkedPlaceEncoder(n_chunks=4, trainer="ridge", top_chunks=2)
    model.fit(small_route.reference, progress=lambda *a: progress.append(a))
    # one unit per class: the chunk classifier's 4, then every chunk encoder's Στ
    units = 4 + sum(sum(enc.periods_) for enc in model.chunk_encoders_)
    assert progress[-1][1] == progress[-1][2] == units
    loc = model.localize(small_route.query)
    n = small_route.query.shape[0]
    p5 = float(np.mean(np.abs(loc.index - np.arange(n)) <= 5))
    assert p5 > 20 * 11 / n
    assert set(np.unique(loc.chunk)) <= {0, 1, 2, 3}
    # the chunk reported is the chunk holding the answered index
    assert np.array_equal(np.searchsorted(model.chunk_bounds_, loc.index, side="right") - 1, loc.chunk)


def test_chunked_training_in_parallel_processes_matches_serial(tiny_route: SyntheticRoute) -> None:
    serial = ChunkedPlaceEncoder(n_chunks=3, trainer="ridge", n_jobs=1).fit(tiny_route.reference)
    parallel = ChunkedPlaceEncoder(n_chunks=3, trainer="ridge", n_jobs=2).fit(tiny_route.reference)
    np.testing.assert_array_equal(serial.predict(tiny_route.query), parallel.predict(tiny_route.query))


@pytest.mark.parametrize("trainer", ["logreg", "svm"])
def test_threaded_one_vs_rest_matches_serial(trainer: str, tiny_route: SyntheticRoute) -> None:
    serial = PhaseEncoder(trainer=trainer, n_jobs=1).fit(tiny_route.reference)
    threaded = PhaseEncoder(trainer=trainer, n_jobs=2).fit(tiny_route.reference)
    for a, b in zip(serial.digits_, threaded.digits_, strict=True):
        np.testing.assert_array_equal(a.linear.weight, b.linear.weight)


def test_baselines_share_the_api(small_route: SyntheticRoute) -> None:
    nn = ExactNN().fit(small_route.reference)
    assert nn.score(small_route.query, tolerance=5) > 0.9
    assert nn.footprint().actual_bytes >= small_route.reference.size * 4
    yu = RhythmicEncoder(n_patterns=2, trainer="ridge").fit(small_route.reference)
    pred = yu.predict(small_route.query)
    assert ((pred >= 0) & (pred < small_route.query.shape[0])).all()
    # modulo labels are hard for linear models on few features (the paper's point against
    # Yu et al.); identical train/test must still be far above the 1/400 of guessing
    assert yu.score(small_route.reference) > 10 / small_route.reference.shape[0]


def test_coprime_periods_and_chinese_remainder() -> None:
    for n in (10, 97, 1000, 3576, 10_000):
        for k in (2, 3):
            periods = coprime_periods(n, k)
            assert np.prod(periods) >= n
            for i in range(k):
                for j in range(i + 1, k):
                    assert np.gcd(periods[i], periods[j]) == 1
            idx = np.arange(min(n, 500))
            residues = np.stack([idx % p for p in periods], axis=1)
            assert np.array_equal(crt(residues, periods), idx)


def test_training_statistics_normalise_the_queries(small_route: SyntheticRoute) -> None:
    model = PhaseEncoder(trainer="ridge").fit(small_route.reference)
    one = model.predict(small_route.query[:1])
    many = model.predict(small_route.query)
    assert one[0] == many[0]  # a query alone is treated exactly like in a batch
    shifted = PhaseEncoder(trainer="ridge").fit(small_route.reference + 100.0)
    np.testing.assert_array_equal(shifted.predict(small_route.query + 100.0), many)


def test_sklearn_contract(small_route: SyntheticRoute) -> None:
    model = PhaseEncoder(n_patterns=3, rho=0.25, trainer="ridge", dtype="float16")
    twin = clone(model)
    assert twin.get_params() == model.get_params()
    assert not hasattr(twin, "n_frames_")
    twin.set_params(rho=0.5).fit(small_route.reference)
    assert twin.n_features_in_ == small_route.reference.shape[1]
    assert len(twin.selected_columns_[0]) == round(0.5 * small_route.reference.shape[1])
    assert len(twin.pattern_weights_) == 3


def test_build_model_picks_the_estimator_from_params() -> None:
    assert isinstance(build_model(ModelParams()), PhaseEncoder)
    chunked = build_model(ModelParams(n_chunks=3, trainer="ridge"))
    assert isinstance(chunked, ChunkedPlaceEncoder) and chunked.n_chunks == 3


def test_footprint_matches_the_paper_formula(small_route: SyntheticRoute) -> None:
    d = small_route.reference.shape[1]
    model = PhaseEncoder(n_patterns=2, rho=0.5, trainer="ridge", dtype="float64").fit(
        small_route.reference
    )
    d_sel = round(0.5 * d)
    fp = model.footprint()
    expected = 8 * (d_sel + 1) * sum(model.periods_) + 2 * d / 8
    assert fp.components["encoders"].paper_bytes + fp.components["masks"].paper_bytes == expected
    assert fp.paper_bytes == expected
    assert fp.components["encoders"].actual_bytes == 8 * (d_sel + 1) * sum(model.periods_)
    assert fp.components["masks"].actual_bytes == 2 * int(np.ceil(d / 8))
    int8 = PhaseEncoder(n_patterns=2, rho=0.5, trainer="ridge", dtype="int8").fit(small_route.reference)
    # int8 weights + float32 bias + float32 scale per class
    assert int8.footprint().components["encoders"].actual_bytes == (d_sel + 8) * sum(model.periods_)


def test_chunked_footprint_adds_the_chunk_classifier(small_route: SyntheticRoute) -> None:
    d = small_route.reference.shape[1]
    model = ChunkedPlaceEncoder(n_chunks=4, rho=0.5, chunk_rho=0.25, trainer="ridge").fit(
        small_route.reference
    )
    comps = model.footprint().components
    assert comps["chunk_classifier"].paper_bytes == 8 * 4 * (round(0.25 * d) + 1)
    assert comps["chunk_classifier_mask"].paper_bytes == d / 8


def test_pq_baseline_round_trips(small_route: SyntheticRoute, tmp_path) -> None:
    pytest.importorskip("faiss", reason="PQ is optional; CI installs gridplace[faiss]")
    from service.encoding import PQIndex, load_model, save_model

    model = PQIndex(n_subquantizers=8).fit(small_route.reference)
    assert model.score(small_route.query, tolerance=5) > 0.5
    fp = model.footprint()
    assert fp.components["pq_codes"].actual_bytes == 400 * 8  # one byte per sub-quantiser
    save_model(model, tmp_path / "pq")
    loaded = load_model(tmp_path / "pq")
    np.testing.assert_array_equal(loaded.predict(small_route.query), model.predict(small_route.query))


def test_pq_rejects_a_non_divisor(small_route: SyntheticRoute) -> None:
    pytest.importorskip("faiss", reason="PQ is optional; CI installs gridplace[faiss]")
    from service.encoding import PQIndex
    from service.errors import InvalidParameterError

    with pytest.raises(InvalidParameterError, match="divide"):
        PQIndex(n_subquantizers=7).fit(small_route.reference)

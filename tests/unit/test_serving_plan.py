"""The query fast path: exact, certified float32 decoding equals brute force over every frame.

All routes are SYNTHETIC. "Brute force" scores every frame of the route with the stored
model's float64 arithmetic (``DigitClassifier.log_probs``) and takes the best valid one.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from service.encoding import ChunkedPlaceEncoder, PhaseEncoder
from service.encoding.decoding import reference_localize
from service.encoding.digit_classifier import DigitClassifier
from service.encoding.phases import index_to_labels
from service.encoding.quantization import QuantizedLinear
from service.encoding.serving_plan import ServingPlan, plan_for
from service.encoding.synthetic import smooth_route


def _labels(enc: PhaseEncoder) -> np.ndarray:
    table = getattr(enc, "frame_labels_", None)
    if table is not None:
        return np.asarray(table())
    return index_to_labels(np.arange(enc.n_frames_), enc.periods_)


def _phase_scores(enc: PhaseEncoder, Qn: np.ndarray) -> np.ndarray:
    labels = _labels(enc)
    out = np.zeros((Qn.shape[0], enc.n_frames_))
    for j, dc in enumerate(enc.digits_):
        lp = dc.log_probs(Qn)
        beta = 1.0 / float(getattr(dc, "temperature", None) or 1.0)
        if beta != 1.0:
            from service.encoding.exact_decode import log_softmax_last

            lp = log_softmax_last(dc.linear.scores(Qn[:, dc.columns]) * beta)
        out += lp[:, labels[:, j]]
    return out


def brute_force(model: PhaseEncoder | ChunkedPlaceEncoder, Q: np.ndarray) -> np.ndarray:
    """``(n, N)`` float64 frame scores of the stored model (−inf outside the top chunks)."""
    if isinstance(model, PhaseEncoder):
        Qn = model._transform(Q)
        return _phase_scores(model, Qn)
    Qn = model.normalizer_.transform(Q)
    clp = model.chunk_classifier_.log_probs(Qn)
    m = min(model.top_chunks, len(model.chunk_encoders_))
    top = np.argsort(-clp, axis=1, kind="stable")[:, :m]
    out = np.full((Q.shape[0], model.n_frames_), -np.inf)
    for c, enc in enumerate(model.chunk_encoders_):
        rows = np.flatnonzero((top == c).any(axis=1))
        s, e = model.chunk_bounds_[c], model.chunk_bounds_[c + 1]
        out[rows, s:e] = _phase_scores(enc, Qn[rows]) + clp[rows, c, None]
    return out


def check_exact(model: PhaseEncoder | ChunkedPlaceEncoder, Q: np.ndarray) -> None:
    F = brute_force(model, Q)
    best = F.max(axis=1)
    for precision in ("float32", "float64"):
        d = ServingPlan(model).decode(Q, precision)  # type: ignore[arg-type]
        assert ((d.index >= 0) & (d.index < model.n_frames_)).all()
        # the answer is a best frame (equal scores only on an exact tie)
        np.testing.assert_array_equal(F[np.arange(Q.shape[0]), d.index], best)
        # the index is certified; a float32 score carries float32 rounding of products and
        # log-sum-exps whose terms reach 1/T (tens, for a calibrated prototype temperature)
        atol = 1e-4 if precision == "float32" else 1e-6
        np.testing.assert_allclose(d.log_score, best, rtol=1e-5, atol=atol)
        bounds = getattr(model, "chunk_bounds_", np.array([0, model.n_frames_]))
        np.testing.assert_array_equal(np.searchsorted(bounds, d.index, side="right") - 1, d.chunk)


@given(
    periods=st.lists(st.integers(2, 9), min_size=1, max_size=3).map(tuple).filter(
        lambda p: math.prod(p) >= 4
    ),
    frac=st.floats(0.3, 1.0),
    seed=st.integers(0, 2**16),
)
@settings(max_examples=30, deadline=None)
def test_phase_encoder_decodes_the_best_valid_frame(
    periods: tuple[int, ...], frac: float, seed: int
) -> None:
    n = max(2, int(frac * math.prod(periods)))  # ∏τ > N: codes past the route exist
    route = smooth_route(n, 12, seed=seed)
    model = PhaseEncoder(periods=periods, rho=0.6, trainer="ridge").fit(route.reference)
    Q = np.concatenate([route.query, np.random.default_rng(seed).standard_normal((20, 12)) * 3])
    check_exact(model, Q.astype(np.float64))


@pytest.mark.parametrize("dtype", ["float64", "float32", "float16", "int8"])
@pytest.mark.parametrize("top_chunks", [1, 2, 5])
def test_chunked_encoder_decodes_the_best_frame_of_its_top_chunks(dtype: str, top_chunks: int) -> None:
    route = smooth_route(437, 24, seed=11)  # uneven chunks, periods differ between chunks
    model = ChunkedPlaceEncoder(n_chunks=5, n_patterns=2, rho=0.5, trainer="ridge",
                                dtype=dtype, top_chunks=top_chunks).fit(route.reference)  # fmt: skip
    check_exact(model, route.query.astype(np.float64))


def test_identical_to_the_beam_decoder_where_the_beam_is_exact() -> None:
    route = smooth_route(3000, 32, seed=5)
    model = ChunkedPlaceEncoder(n_chunks=3, n_patterns=2, rho=0.5, trainer="ridge",
                                beam_width=64).fit(route.reference)  # fmt: skip
    assert all(max(e.periods_) <= 64 for e in model.chunk_encoders_)  # k = 2, τ ≤ 64: exact
    Q = route.query.astype(np.float64)
    index, chunk, score = reference_localize(model, Q)
    loc = model.localize(Q)
    np.testing.assert_array_equal(loc.index, index)
    np.testing.assert_array_equal(loc.chunk, chunk)
    np.testing.assert_allclose(loc.log_score, score, rtol=1e-5, atol=1e-6)
    # the same float64 sums; a multi-threaded BLAS may add them in another order (1 ulp)
    np.testing.assert_allclose(plan_for(model).decode(Q, "float64").log_score, score,
                               rtol=1e-14, atol=0)  # fmt: skip


def test_a_float32_near_tie_is_recomputed_in_float64() -> None:
    """Two classes whose weights differ below float32 resolution: float32 cannot rank them,
    so the plan must not trust it, and the float64 answer is returned."""
    route = smooth_route(200, 16, seed=2)
    model = PhaseEncoder(periods=(20, 10), rho=1.0, trainer="ridge", dtype="float64").fit(
        route.reference
    )
    dc = model.digits_[1]
    W, b = dc.linear.weight.copy(), dc.linear.bias.copy()
    W[3] = W[4] * (1 + 1e-9)  # class 3 is class 4 scaled by 1 + 1e-9: float32 rounds them equal
    b[3] = b[4]
    model.digits_[1] = DigitClassifier(dc.columns, QuantizedLinear(W, b))
    model._set_fitted(model.n_frames_, model.n_features_in_)
    Q = route.reference[np.arange(200) % 10 == 4].astype(np.float64)  # digit 1 is 4: near tie
    plan = ServingPlan(model)
    d32, d64 = plan.decode(Q), plan.decode(Q, "float64")
    assert d32.rescored.any()
    np.testing.assert_array_equal(d32.index, d64.index)
    check_exact(model, Q)


def test_a_batch_answers_as_its_rows_one_by_one() -> None:
    route = smooth_route(900, 24, seed=4)
    model = ChunkedPlaceEncoder(n_chunks=4, trainer="ridge").fit(route.reference)
    Q = route.query.astype(np.float64)[:200]
    batch = model.localize(Q)
    one = [model.localize(Q[i : i + 1]) for i in range(Q.shape[0])]
    np.testing.assert_array_equal(batch.index, [o.index[0] for o in one])
    np.testing.assert_array_equal(batch.chunk, [o.chunk[0] for o in one])
    np.testing.assert_allclose(batch.confidence, [o.confidence[0] for o in one], rtol=1e-5)
    F = model.frame_log_scores(Q[:20])
    np.testing.assert_array_equal(F.argmax(axis=1), batch.index[:20])
    for i in range(3):
        np.testing.assert_allclose(model.frame_log_scores(Q[i : i + 1])[0], F[i], rtol=1e-12)


@pytest.mark.parametrize("rows", [2, 3, 9, 10, 40])
def test_batches_of_few_rows_multiply_them_one_by_one_with_the_same_answers(rows: int) -> None:
    from service.encoding.factory import ModelParams, build_model
    from service.encoding.serving_blocks import gemv_rows

    assert gemv_rows(1 << 20) == 10 and gemv_rows(1 << 30) == 4
    route = smooth_route(600, 48, query_noise=0.5, seed=6)  # SYNTHETIC
    model = build_model(ModelParams.parse(encoder_preset="robust")).fit(route.reference)
    Q = route.query.astype(np.float64)[: 3 * rows]
    blocks = [model.localize(Q[s : s + rows]) for s in range(0, Q.shape[0], rows)]
    one = [model.localize(Q[i : i + 1]) for i in range(Q.shape[0])]
    np.testing.assert_array_equal(np.concatenate([b.index for b in blocks]), [o.index[0] for o in one])
    np.testing.assert_allclose(np.concatenate([b.confidence for b in blocks]),
                               [o.confidence[0] for o in one], rtol=1e-5)  # fmt: skip


def test_frame_scores_match_brute_force() -> None:
    route = smooth_route(500, 20, seed=8)
    for model in (PhaseEncoder(periods=(23, 23), trainer="ridge").fit(route.reference),
                  ChunkedPlaceEncoder(n_chunks=3, top_chunks=2, trainer="ridge").fit(route.reference)):  # fmt: skip
        Q = route.query[:30].astype(np.float64)
        np.testing.assert_allclose(model.frame_log_scores(Q), brute_force(model, Q), rtol=1e-12)


class _RedundantEncoder(PhaseEncoder):
    """A phase encoder with an extra digit (frame mod 7) beside its mixed-radix digits:
    an arbitrary label table, as a redundant code would give."""

    def frame_labels_(self) -> np.ndarray:
        base = index_to_labels(np.arange(self.n_frames_), self.periods_)
        return np.column_stack([base, np.arange(self.n_frames_) % 7])


def test_any_label_table_and_temperature_is_decoded_exactly() -> None:
    route = smooth_route(300, 16, seed=9)
    model = _RedundantEncoder(periods=(20, 15), trainer="ridge").fit(route.reference)
    Xn = model._transform(route.reference.astype(np.float64))
    extra = DigitClassifier.fit(Xn, np.arange(300) % 7, 7, rho=0.5, gamma=None, trainer="ridge",
                                C=4.0, dtype="float32", random_state=0)  # fmt: skip
    model.digits_.append(extra)
    model._set_fitted(model.n_frames_, model.n_features_in_)
    assert plan_for(model).phases[0].labels is not None
    check_exact(model, route.query.astype(np.float64))
    object.__setattr__(model.digits_[0], "temperature", 2.5)  # the contract's per-digit T
    model._set_fitted(model.n_frames_, model.n_features_in_)
    check_exact(model, route.query.astype(np.float64))
    F = model.frame_log_scores(route.query[:10])
    np.testing.assert_allclose(F, brute_force(model, route.query[:10].astype(np.float64)), rtol=1e-12)


def test_a_refit_model_gets_a_new_plan() -> None:
    route = smooth_route(200, 12, seed=1)
    model = PhaseEncoder(trainer="ridge").fit(route.reference)
    first = plan_for(model)
    assert plan_for(model) is first
    model.fit(route.reference[:150])
    assert plan_for(model) is not first and plan_for(model).n_frames == 150


def _one_by_one(plan: ServingPlan, Q: np.ndarray) -> tuple[np.ndarray, ...]:
    rows = [plan.decode(Q[i : i + 1]) for i in range(Q.shape[0])]
    fields = ("index", "chunk", "log_score", "rescored")
    return tuple(np.concatenate([getattr(r, f) for r in rows]) for f in fields)


@pytest.mark.parametrize("dtype", ["float32", "int8"])
@pytest.mark.parametrize("top_chunks", [1, 2, 5])
def test_the_single_query_path_answers_as_the_batch_path(dtype: str, top_chunks: int) -> None:
    """One row takes :mod:`service.encoding.single_query`: same answers as in a batch."""
    route = smooth_route(437, 24, seed=13)  # uneven chunks: digits of unequal periods (padding)
    model = ChunkedPlaceEncoder(n_chunks=5, n_patterns=2, rho=0.5, trainer="ridge",
                                dtype=dtype, top_chunks=top_chunks).fit(route.reference)  # fmt: skip
    plan = ServingPlan(model)
    assert plan._single is not None
    Q = np.concatenate([route.query, np.random.default_rng(3).standard_normal((40, 24)) * 3])
    index, chunk, score, _ = _one_by_one(plan, Q)
    batch = plan.decode(Q)  # more than one row: the batch path
    np.testing.assert_array_equal(index, batch.index)
    np.testing.assert_array_equal(chunk, batch.chunk)
    np.testing.assert_allclose(score, batch.log_score, rtol=1e-6, atol=1e-9)
    F = brute_force(model, Q)
    np.testing.assert_array_equal(F[np.arange(Q.shape[0]), index], F.max(axis=1))


def test_the_single_query_path_of_a_phase_encoder_with_a_temperature() -> None:
    route = smooth_route(300, 16, seed=6)
    model = PhaseEncoder(periods=(20, 17), rho=0.6, trainer="ridge").fit(route.reference)  # ∏τ > N
    object.__setattr__(model.digits_[1], "temperature", 0.7)
    model._set_fitted(model.n_frames_, model.n_features_in_)
    plan = ServingPlan(model)
    assert plan._single is not None and plan._single.beta is not None
    Q = np.concatenate([route.query, np.random.default_rng(5).standard_normal((30, 16)) * 4])
    index, chunk, score, _ = _one_by_one(plan, Q)
    F = brute_force(model, Q)
    np.testing.assert_array_equal(F[np.arange(Q.shape[0]), index], F.max(axis=1))
    np.testing.assert_allclose(score, F.max(axis=1), rtol=1e-5, atol=1e-6)
    np.testing.assert_array_equal(chunk, 0)


def test_a_single_near_tie_and_a_huge_query_fall_back_to_float64() -> None:
    route = smooth_route(200, 16, seed=2)
    model = PhaseEncoder(periods=(20, 10), rho=1.0, trainer="ridge", dtype="float64").fit(
        route.reference
    )
    dc = model.digits_[1]
    W, b = dc.linear.weight.copy(), dc.linear.bias.copy()
    W[3], b[3] = W[4] * (1 + 1e-9), b[4]  # float32 cannot rank classes 3 and 4
    model.digits_[1] = DigitClassifier(dc.columns, QuantizedLinear(W, b))
    model._set_fitted(model.n_frames_, model.n_features_in_)
    plan = ServingPlan(model)
    Q = route.reference[np.arange(200) % 10 == 4].astype(np.float64)  # digit 1 is 4: near tie
    index, _, _, rescored = _one_by_one(plan, Q)
    assert rescored.any()
    np.testing.assert_array_equal(rescored, plan.decode(Q).rescored)  # the same certificate
    np.testing.assert_array_equal(index, plan.decode(Q, "float64").index)
    huge = route.reference[:1].astype(np.float64) * 1e30  # z-scores beyond the 1-row path's range
    np.testing.assert_array_equal(plan.decode(huge).index, plan.decode(huge, "float64").index)


def test_label_tables_are_left_to_the_batch_path() -> None:
    route = smooth_route(300, 16, seed=9)
    model = _RedundantEncoder(periods=(20, 15), trainer="ridge").fit(route.reference)
    Xn = model._transform(route.reference.astype(np.float64))
    model.digits_.append(DigitClassifier.fit(Xn, np.arange(300) % 7, 7, rho=0.5, gamma=None,
                                             trainer="ridge", C=4.0, dtype="float32",
                                             random_state=0))  # fmt: skip
    model._set_fitted(model.n_frames_, model.n_features_in_)
    assert ServingPlan(model)._single is None
    check_exact(model, route.query[:1].astype(np.float64))


class _FrontEndPlan(ServingPlan):
    """A plan whose front-end is more than mean and scale (as a projection would be)."""

    def normalise(self, Q: np.ndarray, dtype: type = np.float64) -> np.ndarray:
        return (super().normalise(Q, np.float64) * 1.5).astype(dtype)


def test_a_front_end_beyond_mean_and_scale_is_the_plans_own_in_the_single_path() -> None:
    route = smooth_route(437, 24, seed=13)
    model = ChunkedPlaceEncoder(n_chunks=5, trainer="ridge", top_chunks=2).fit(route.reference)
    assert ServingPlan(model)._single.fused_z  # type: ignore[union-attr]
    plan = _FrontEndPlan(model)
    assert plan._single is not None and not plan._single.fused_z
    Q = route.query.astype(np.float64)
    index, chunk, _, _ = _one_by_one(plan, Q)
    batch = plan.decode(Q)
    np.testing.assert_array_equal(index, batch.index)
    np.testing.assert_array_equal(chunk, batch.chunk)


@given(
    periods=st.lists(st.integers(2, 40), min_size=1, max_size=4, unique=True).map(tuple),
    frac=st.floats(0.2, 1.0),
    components=st.sampled_from([None, 4, 10]),
    trainer=st.sampled_from(["prototype", "ridge"]),
    temperature=st.sampled_from([None, 0.05, 3.0]),
    seed=st.integers(0, 2**16),
)
@settings(max_examples=30, deadline=None)
def test_residue_codes_decode_the_best_frame_exactly(
    periods: tuple[int, ...], frac: float, components: int | None, trainer: str,
    temperature: float | None, seed: int,
) -> None:  # fmt: skip
    n = max(2, min(300, int(frac * math.lcm(*periods))))
    route = smooth_route(n, 12, seed=seed)
    model = PhaseEncoder(code="residue", periods=periods, rho=1.0, trainer=trainer,
                         n_components=components, temperature=temperature).fit(route.reference)  # fmt: skip
    phase = plan_for(model).phases[0]
    assert phase.tabled or len(periods) == 1
    assert phase.labels is None if phase.residue else True  # residues are computed, not stored
    if phase.residue:  # what the table would have given, without making it
        table = model.frame_labels_()
        np.testing.assert_array_equal(phase.frame_labels(np.arange(n)), table)
        np.testing.assert_array_equal(phase.last, table[-1])
        assert phase.periods == tuple(d.n_classes for d in phase.digits)
    Q = np.concatenate([route.query, np.random.default_rng(seed).standard_normal((10, 12)) * 3])
    check_exact(model, Q.astype(np.float64))
    np.testing.assert_allclose(model.frame_log_scores(Q[:8]), brute_force(model, Q[:8]), rtol=1e-12)
    index, _, score = reference_localize(model, Q)
    np.testing.assert_array_equal(model.localize(Q).index, index)
    # localize answers with the float32 score of the certified index (see check_exact)
    np.testing.assert_allclose(model.localize(Q).log_score, score, rtol=1e-5, atol=1e-4)


@pytest.mark.parametrize("dtype", ["float32", "int8"])
@pytest.mark.parametrize("top_chunks", [1, 3])
def test_chunked_residue_routes_with_a_shared_projection_decode_exactly(
    dtype: str, top_chunks: int
) -> None:
    route = smooth_route(437, 24, seed=11)
    model = ChunkedPlaceEncoder(n_chunks=4, n_patterns=4, code="residue", rho=1.0,
                                trainer="prototype", n_components=12, dtype=dtype,
                                top_chunks=top_chunks).fit(route.reference)  # fmt: skip
    assert all(e.normalizer_ is None for e in model.chunk_encoders_)  # one front-end, shared
    Q = route.query.astype(np.float64)
    check_exact(model, Q)
    np.testing.assert_allclose(model.frame_log_scores(Q[:20]), brute_force(model, Q[:20]),
                               rtol=1e-12)  # fmt: skip
    index, chunk, _ = reference_localize(model, Q)
    loc = model.localize(Q)
    np.testing.assert_array_equal(loc.index, index)
    np.testing.assert_array_equal(loc.chunk, chunk)


def test_a_large_batch_is_decoded_in_row_blocks_with_the_same_answers(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    import service.encoding.serving_plan as sp

    route = smooth_route(400, 16, seed=12)
    for model in (PhaseEncoder(code="residue", n_patterns=1, trainer="prototype",
                               n_components=8).fit(route.reference),
                  ChunkedPlaceEncoder(n_chunks=3, trainer="ridge").fit(route.reference)):  # fmt: skip
        Q = route.query.astype(np.float64)
        whole = ServingPlan(model).decode(Q)
        monkeypatch.setattr(sp, "_BLOCK_SCORES", 3 * 400)  # a few rows per block
        blocked = ServingPlan(model).decode(Q)
        monkeypatch.undo()
        for field in ("index", "chunk"):
            np.testing.assert_array_equal(getattr(blocked, field), getattr(whole, field))
        # a last block of one row takes the one-query path: scores agree to float32 rounding
        np.testing.assert_allclose(blocked.log_score, whole.log_score, rtol=1e-6, atol=1e-9)

"""The ``drive`` preset: a residue code that grows as √N with binary class templates, saved
and loaded bit-identically, tracked by the code scorer (SYNTHETIC routes)."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from service.encoding.artifacts import load_model, save_model
from service.encoding.drive_scoring import CodeScorer, drive_scorer
from service.encoding.exact_decode import frame_scores_residue, frame_scores_table
from service.encoding.factory import ModelParams, build_model
from service.encoding.quantization import QuantizedLinear
from service.encoding.residue import code_sum, residue_periods
from service.encoding.sequence import sequence_localize
from service.encoding.serving_blocks import _binary_float32
from service.encoding.serving_plan import plan_for
from service.encoding.synthetic import smooth_route


@settings(max_examples=40, deadline=None)
@given(st.integers(1, 40), st.integers(1, 300), st.integers(0, 2**31 - 1))
def test_binary_weights_are_signs_times_column_widths(rows: int, cols: int, seed: int) -> None:
    W = np.random.default_rng(seed).normal(size=(rows, cols))
    q = QuantizedLinear.from_dense(W, np.zeros(rows), "binary")
    D, b = q.dequantized()
    np.testing.assert_array_equal(np.sign(D), np.where(W > 0, 1.0, -1.0))
    np.testing.assert_allclose(np.abs(D), np.abs(W).mean(axis=0)[None, :].repeat(rows, 0), rtol=1e-6)
    assert not b.any() and q.dtype == "binary"
    assert q.nbytes == rows * math.ceil(cols / 8) + 4 * cols
    back = QuantizedLinear.from_arrays(q.to_arrays("w"), "w")
    np.testing.assert_array_equal(back.dequantized()[0], D)


def test_the_code_grows_as_the_square_root_of_the_route() -> None:
    for n in (3_576, 100_000, 1_000_000):
        periods = residue_periods(n, 2, 44.0, 0.5)
        assert math.lcm(*periods) >= n
        assert abs(sum(periods) - code_sum(n, 44.0, 0.5)) <= 0.02 * code_sum(n, 44.0, 0.5)
    assert code_sum(100, 44.0, 0.5) == 100  # never more classes than frames
    assert code_sum(1_000_000, 44.0, 0.5) == 44_000


def test_the_drive_preset_saves_loads_and_tracks(tmp_path: Path) -> None:
    route = smooth_route(2_000, 64, query_noise=0.4, seed=5)  # SYNTHETIC
    params = ModelParams(encoder_preset="drive")
    assert params.dtype == "binary" and params.code_exponent == 0.5
    model = build_model(params).fit(route.reference)
    assert sum(model.periods_) == code_sum(2_000, 44.0, 0.5) or sum(model.periods_) <= 2_000
    save_model(model, tmp_path / "m")
    loaded = load_model(tmp_path / "m")
    np.testing.assert_array_equal(loaded.frame_log_scores(route.query[:50]),
                                  model.frame_log_scores(route.query[:50]))  # fmt: skip
    assert isinstance(drive_scorer(loaded), CodeScorer)
    track = sequence_localize(loaded, route.query)
    truth = np.arange(2_000)
    single = np.mean(np.abs(loaded.localize(route.query).index - truth) <= 5)
    drive = np.mean(np.abs(track.index - truth) <= 5)
    assert drive > 0.95 and drive > single, (single, drive)
    encoders = loaded.footprint().to_dict()["components"]["encoders"]["actual_bytes"]
    assert encoders <= sum(model.periods_) * (128 // 8) + 2 * 4 * 128 + 64


class _TablePlan:
    """The plan of a residue model with its labels given as a stored table instead."""

    def __init__(self, plan: object) -> None:
        phase = plan.phases[0]  # type: ignore[attr-defined]
        table = phase.frame_labels(np.arange(phase.n_frames))
        self.phases = [replace(phase, labels=table, residue=False)]
        self.normalise = plan.normalise  # type: ignore[attr-defined]


@settings(max_examples=20, deadline=None)
@given(n=st.integers(30, 900), seed=st.integers(0, 2**16))
def test_computed_residue_labels_score_as_a_stored_table(n: int, seed: int) -> None:
    route = smooth_route(n, 16, query_noise=0.4, seed=seed)  # SYNTHETIC
    model = build_model(ModelParams(encoder_preset="drive")).fit(route.reference)
    plan = plan_for(model)
    phase = plan.phases[0]
    if len(phase.digits) < 2:  # a route this short may get one digit: mixed radix, no residue
        return
    assert phase.residue and phase.labels is None  # no (N, k) table is kept
    frames = np.arange(n)
    np.testing.assert_array_equal(phase.frame_labels(frames),
                                  frames[:, None] % np.asarray(phase.periods))  # fmt: skip
    computed, stored = CodeScorer(model, plan), CodeScorer(model, _TablePlan(plan))
    assert computed.labels is None and not computed.order and stored.labels is not None
    Q = route.query[np.random.default_rng(seed).integers(0, n, 3)]
    rng = np.random.default_rng(seed)
    for a, b in zip(computed.prepare_many(Q), stored.prepare_many(Q), strict=True):
        idx = rng.integers(0, n, 40)
        np.testing.assert_array_equal(computed.frames(a, idx), stored.frames(b, idx))
        np.testing.assert_array_equal(computed.sample_scores(a), stored.sample_scores(b))
        np.testing.assert_array_equal(computed.next_scores(a), stored.next_scores(b))
        np.testing.assert_array_equal(computed.candidates(a, 7), stored.candidates(b, 7))
        np.testing.assert_array_equal(computed.full(a), stored.full(b))
        np.testing.assert_array_equal(computed.frames(a, idx), stored.frames(b, idx))  # full now
    table = phase.frame_labels(frames)
    lp = np.random.default_rng(seed).standard_normal((4, len(phase.digits), phase.width))
    np.testing.assert_array_equal(frame_scores_residue(lp, phase.periods, n),
                                  frame_scores_table(lp, table))  # fmt: skip


@settings(max_examples=25, deadline=None)
@given(rows=st.integers(1, 300), cols=st.integers(1, 40), block=st.integers(1, 64),
       seed=st.integers(0, 2**16))  # fmt: skip
def test_binary_weights_widen_to_float32_as_the_stored_form_defines_them(
    rows: int, cols: int, block: int, seed: int
) -> None:
    rng = np.random.default_rng(seed)
    W = rng.standard_normal((rows, cols))
    lin = QuantizedLinear.from_dense(W, np.zeros(rows), "binary")
    got = _binary_float32(lin.weight, lin.width, block)
    assert got.dtype == np.float32 and got.shape == (rows, cols)
    np.testing.assert_array_equal(got, lin.dequantized()[0].astype(np.float32))

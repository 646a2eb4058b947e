"""The ``drive`` preset: a residue code that grows as √N with binary class templates, saved
and loaded bit-identically, tracked by the code scorer (SYNTHETIC routes)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from service.encoding.artifacts import load_model, save_model
from service.encoding.drive_scoring import CodeScorer, drive_scorer
from service.encoding.factory import ModelParams, build_model
from service.encoding.quantization import QuantizedLinear
from service.encoding.residue import code_sum, residue_periods
from service.encoding.sequence import sequence_localize
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

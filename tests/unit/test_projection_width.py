"""The default's projection width is chosen from the route: never more than exact NN on the
route's uint8 rows (``N·d`` bytes), at most 0.7 of the training rows, recorded in the manifest
(SYNTHETIC routes)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from service.encoding import ModelParams, build_model, save_model
from service.encoding.chunk_training import fit_front_end, plan_chunks
from service.encoding.projection_width import ROW_FRACTION, choose_width, model_bytes
from service.encoding.synthetic import smooth_route


@settings(max_examples=40, deadline=None)
@given(n=st.integers(20, 400), d=st.integers(24, 300), chunks=st.sampled_from([1, 2, 3]),
       traversals=st.sampled_from([1, 2]), seed=st.integers(0, 3))  # fmt: skip
def test_the_default_never_stores_more_than_the_uint8_rows(
    n: int, d: int, chunks: int, traversals: int, seed: int
) -> None:
    route = smooth_route(n, d, seed=seed)
    X = route.reference if traversals == 1 else [route.reference, route.query]
    model = build_model(ModelParams(n_chunks=chunks)).fit(X)
    stored = model.footprint().actual_bytes
    width = model.normalizer_.projection.n_components  # type: ignore[union-attr]
    assert stored <= n * d, (stored, n * d, width)
    assert width <= max(1, int(ROW_FRACTION * n * traversals))


def test_a_short_route_of_wide_rows_the_case_that_stored_more() -> None:
    rng = np.random.default_rng(0)
    X = rng.integers(0, 255, (300, 2048)).astype(np.float64)
    default = build_model(ModelParams()).fit(X)
    fixed = build_model(ModelParams(auto_width=False)).fit(X)
    assert fixed.footprint().actual_bytes == 621_960 > 300 * 2048  # PCA-256 as it was
    assert default.footprint().actual_bytes <= 300 * 2048
    assert default.normalizer_.projection.n_components == 210  # type: ignore[union-attr]


def test_the_count_is_exact_for_one_prototype_per_frame() -> None:
    for n, d in ((120, 64), (300, 2048), (50, 40)):
        route = smooth_route(n, d, seed=1)
        model = build_model(ModelParams()).fit(route.reference)
        width = model.normalizer_.projection.n_components  # type: ignore[union-attr]
        assert model.footprint().actual_bytes == model_bytes(width, d, [n], "int8")


@settings(max_examples=200, deadline=None)
@given(requested=st.integers(1, 512), n=st.integers(2, 5000), d=st.integers(1, 6000),
       rows_per_place=st.sampled_from([1, 2]), k=st.integers(1, 3),
       dtype=st.sampled_from(["int8", "float32", "float16"]))  # fmt: skip
def test_the_width_is_the_widest_that_fits(requested: int, n: int, d: int, rows_per_place: int,
                                           k: int, dtype: str) -> None:  # fmt: skip
    classes = [max(2, n // k)] * k
    choice = choose_width(requested, n, n * rows_per_place, d, classes, dtype)
    wanted = max(1, min(requested, int(ROW_FRACTION * n * rows_per_place)))
    fits = [m for m in range(1, wanted + 1) if model_bytes(m, d, classes, dtype) <= n * d]
    if fits:
        assert choice.width == max(fits) and choice.within_cap
        assert choice.estimated_bytes <= choice.cap_bytes == n * d
    else:  # not even one component fits: the width precision asks for, and said so
        assert choice.width == wanted and not choice.within_cap


def test_the_manifest_records_the_choice(tmp_path: Path) -> None:
    route = smooth_route(150, 96, seed=2)
    manifest = save_model(build_model(ModelParams()).fit(route.reference), tmp_path / "m")
    stored = json.loads((tmp_path / "m" / "manifest.json").read_text())["projection"]
    assert stored == manifest["projection"]
    assert stored["requested_components"] == 256 and stored["auto_width"] is True
    assert stored["components"] < 256 and stored["within_cap"] is True
    assert stored["stored_bytes"] <= stored["cap_bytes"] == 150 * 96
    assert "0.7 of the training rows" in stored["rule"]
    paper = save_model(build_model(ModelParams(encoder_preset="paper")).fit(route.reference),
                       tmp_path / "p")  # fmt: skip
    assert paper["projection"] is None  # no projection to choose


@pytest.mark.parametrize("chunks", [2, 4])
def test_the_queue_front_end_chooses_the_same_width(chunks: int) -> None:
    """Queue jobs fit the route's front-end on their own (``fit_front_end``): the same width
    as the in-process chunked model."""
    route = smooth_route(240, 120, seed=3).reference
    params = ModelParams(n_chunks=chunks)
    model = build_model(params).fit(route)
    front = fit_front_end(route, params.model_dump(), plan_chunks(240, chunks))
    assert front.n_outputs == model.normalizer_.n_outputs  # type: ignore[union-attr]
    assert model.footprint().actual_bytes <= 240 * 120


def test_the_bound_is_met_from_ten_frames_of_wide_rows() -> None:
    for d in (512, 2048, 5120):
        assert choose_width(256, 10, 10, d, [10], "int8").within_cap
        assert not choose_width(256, 9, 9, d, [9], "int8").within_cap  # the statistics alone
    assert not choose_width(256, 5000, 5000, 9, [5000], "int8").within_cap  # d ≤ 9: never


def test_the_small_routes_benchmark_runs(monkeypatch: pytest.MonkeyPatch) -> None:
    from service.bench import small_routes_bench as bench

    monkeypatch.setattr(bench, "SIZES", (60,))
    monkeypatch.setattr(bench, "SLICES_PER_SIZE", 2)
    route = smooth_route(bench.HALF_B + 200, 48, seed=5)  # SYNTHETIC, long enough for half B
    rows = bench.measure("synthetic", route.reference, route.query)
    assert [r["start"] for r in rows] == [bench.HALF_B, bench.HALF_B + 60]
    (summary,) = bench.summarise(rows)
    assert summary["default"]["bytes"] <= 60 * 48 < summary["pca256"]["bytes"]
    assert summary["default"]["components"] == choose_width(256, 60, 60, 48, [60], "int8").width
    assert 0 <= summary["default"]["single"] <= 1

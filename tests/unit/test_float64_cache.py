"""Float64 re-scoring weights are kept within the budget and give the same answers."""

from __future__ import annotations

import gc

import numpy as np
import pytest

from service.encoding import ChunkedPlaceEncoder, float64_cache
from service.encoding.serving_plan import ServingPlan
from service.encoding.synthetic import smooth_route


def _model(dtype: str = "int8") -> ChunkedPlaceEncoder:
    route = smooth_route(400, 24, seed=21)
    return ChunkedPlaceEncoder(n_chunks=3, n_patterns=2, rho=0.5, trainer="ridge",
                               dtype=dtype).fit(route.reference)  # fmt: skip


def test_kept_weights_are_those_made_per_call() -> None:
    plan = ServingPlan(_model())
    block = plan.phases[0].digits[0]
    W, b = block.dense64()
    assert block.dense64()[0] is W  # kept
    W2, b2 = block._make_dense64()
    np.testing.assert_array_equal(W, W2)
    np.testing.assert_array_equal(b, b2)


def test_the_budget_bounds_what_is_kept_and_freed_blocks_return_to_it(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    gc.collect()
    before = float64_cache.used_bytes()
    plan = ServingPlan(_model())
    blocks = [d for p in plan.phases for d in p.digits]
    size = sum(x.nbytes for x in blocks[0]._make_dense64())
    monkeypatch.setattr(float64_cache, "CACHE_BYTES", before + size)  # room for one block
    for block in blocks:
        block.dense64()
    assert sum(bool(block.kept64) for block in blocks) == 1
    assert float64_cache.used_bytes() == before + size
    del plan, blocks, block
    gc.collect()
    assert float64_cache.used_bytes() == before


def test_answers_are_the_same_with_and_without_kept_weights(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    model = _model("float32")
    Q = smooth_route(400, 24, seed=21).query.astype(np.float64)
    kept = ServingPlan(model).decode(Q, "float64")
    monkeypatch.setattr(float64_cache, "CACHE_BYTES", 0)
    fresh = ServingPlan(model).decode(Q, "float64")
    np.testing.assert_array_equal(kept.index, fresh.index)
    np.testing.assert_array_equal(kept.log_score, fresh.log_score)

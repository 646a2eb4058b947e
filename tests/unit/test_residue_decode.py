"""Branch-and-bound decoding of residue codes equals enumerating every frame of the route."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from service.encoding import residue_decode as rd
from service.encoding.exact_decode import table_decode
from service.encoding.residue_decode import is_residue_table, residue_decode
from service.encoding.serving_plan import plan_for


def _lp(rng: np.random.Generator, rows: int, periods: list[int], levels: int | None) -> np.ndarray:
    """Padded ``(rows, k, τ_max)`` digit scores; ``levels`` draws from a few values (ties)."""
    width = max(periods)
    lp = np.full((rows, len(periods), width), -np.inf)
    for j, t in enumerate(periods):
        if levels is None:
            lp[:, j, :t] = rng.normal(size=(rows, t)) * rng.uniform(0.1, 5.0)
        else:
            lp[:, j, :t] = -rng.integers(0, levels, size=(rows, t)).astype(float)
    return lp


@settings(max_examples=150, deadline=None)
@given(
    periods=st.lists(st.integers(1, 40), min_size=1, max_size=3),
    n_frames=st.integers(1, 3000),
    levels=st.one_of(st.none(), st.integers(1, 4)),
    margin=st.floats(0.0, 3.0),
    seed=st.integers(0, 2**31 - 1),
)
def test_equals_the_full_enumeration(periods: list[int], n_frames: int, levels: int | None,
                                     margin: float, seed: int) -> None:  # fmt: skip
    rng = np.random.default_rng(seed)
    lp = _lp(rng, 4, periods, levels)
    labels = np.arange(n_frames)[:, None] % np.asarray(periods)[None, :]
    idx, best, second = table_decode(lp, labels)
    margins = np.full(4, margin)
    r_idx, r_best, r_second = residue_decode(lp, periods, n_frames, margins)
    np.testing.assert_array_equal(r_idx, idx)  # the lowest frame on ties, too
    np.testing.assert_array_equal(r_best, best)  # the same sums in the same order
    assert np.all(r_second <= best)
    # the certification verdict is the full enumeration's
    np.testing.assert_array_equal(r_best - r_second > margins, best - second > margins)


def test_a_confident_query_scores_a_few_classes_not_the_route(monkeypatch: pytest.MonkeyPatch) -> None:
    periods, n = [997, 991], 900_000
    rng = np.random.default_rng(0)
    lp = rng.normal(size=(2, 2, 997)) * 0.01 - 10.0
    target = 123_456
    lp[:, 0, target % 997] = 0.0
    lp[:, 1, target % 991] = 0.0
    lp[:, 1, 991:] = -np.inf
    scored: list[int] = []
    frames_of = rd._frames_of

    def counting(classes: np.ndarray, *args: object) -> tuple[np.ndarray, np.ndarray]:
        f, s = frames_of(classes, *args)  # type: ignore[arg-type]
        scored.append(f.size)
        return f, s

    monkeypatch.setattr(rd, "_frames_of", counting)
    idx, best, _ = residue_decode(lp, periods, n)
    assert idx.tolist() == [target, target]
    assert best.tolist() == [0.0, 0.0]
    assert sum(scored) <= 2 * rd.FIRST_CLASSES * (-(-n // 997))  # ≈ 58k frames, not 1.8M


def test_residue_tables_are_recognised() -> None:
    frames = np.arange(50)[:, None]
    assert is_residue_table(frames % np.array([7, 5]), [7, 5])
    assert not is_residue_table(frames % np.array([7, 5]), [7, 6])
    mixed = np.stack([frames[:, 0] // 7, frames[:, 0] % 7], axis=1)
    assert not is_residue_table(mixed, [8, 7])


@pytest.mark.parametrize("preset", ["drive", "residue"])
def test_residue_presets_are_served_by_branch_and_bound(preset: str) -> None:
    from service.encoding import ModelParams, build_model
    from service.encoding.synthetic import smooth_route

    route = smooth_route(1500, 32, seed=3)
    model = build_model(ModelParams.parse(encoder_preset=preset)).fit(route.reference)
    plan = plan_for(model)
    assert all(p.residue for p in plan.phases)
    Q = route.query[::7].astype(np.float64)
    fast = plan.decode(Q)
    assert all(p.labels is None for p in plan.phases)  # computed, not stored
    plan.phases = tuple(type(p)(**{**p.__dict__, "residue": False,  # the same labels as a table
                                   "labels": p.frame_labels(np.arange(p.n_frames))})
                        for p in plan.phases)  # fmt: skip
    slow = plan.decode(Q)
    np.testing.assert_array_equal(fast.index, slow.index)
    np.testing.assert_array_equal(fast.log_score, slow.log_score)
    np.testing.assert_array_equal(fast.rescored, slow.rescored)

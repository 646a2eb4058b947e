"""Auto-tuning: the choice obeys the budget / target on every set of scores (hypothesis),
and on a SYNTHETIC route the search fits, scores and picks under a budget."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from service.encoding import ModelParams
from service.encoding.autotune import (
    Candidate,
    CandidateScore,
    autotune,
    default_candidates,
    grid_candidates,
    select,
)
from service.encoding.synthetic import SyntheticRoute
from service.errors import InvalidParameterError


def _score(i: int, precision: float, nbytes: int, budget: int | None,
           target: float | None) -> CandidateScore:  # fmt: skip
    return CandidateScore(f"c{i}", {}, precision, nbytes, float(nbytes), 0.0,
                          budget is None or nbytes <= budget,
                          None if target is None else precision >= target)  # fmt: skip


rows = st.lists(st.tuples(st.floats(0, 1), st.integers(1, 10_000)), min_size=1, max_size=12)


@given(rows, st.integers(1, 10_000))
def test_budget_picks_the_most_precise_that_fits(data: list, budget: int) -> None:
    scores = [_score(i, p, b, budget, None) for i, (p, b) in enumerate(data)]
    if not any(s.within_budget for s in scores):
        with pytest.raises(InvalidParameterError, match="no candidate fits"):
            select(scores, budget, None)
        return
    chosen, reason = select(scores, budget, None)
    assert chosen.actual_bytes <= budget and "most precise" in reason
    assert all(s.precision <= chosen.precision for s in scores if s.within_budget)


@given(rows, st.floats(0.01, 1.0), st.none() | st.integers(1, 10_000))
def test_target_picks_the_smallest_that_reaches_it(data: list, target: float,
                                                    budget: int | None) -> None:  # fmt: skip
    scores = [_score(i, p, b, budget, target) for i, (p, b) in enumerate(data)]
    if not any(s.within_budget for s in scores):
        return
    chosen, reason = select(scores, budget, target)
    assert chosen.within_budget
    reach = [s for s in scores if s.within_budget and s.reaches_target]
    if reach:
        assert chosen.reaches_target and chosen.actual_bytes == min(s.actual_bytes for s in reach)
    else:
        assert "no candidate" in reason
        assert chosen.precision == max(s.precision for s in scores if s.within_budget)


def test_grid_names_each_combination_once() -> None:
    base = {"r": ModelParams.parse(trainer="ridge", rho=0.5)}
    cands = grid_candidates(base, {"rho": (0.5, 1.0), "dtype": ("float32", "int8")})
    assert [c.name for c in cands] == ["r[rho=0.5,dtype=float32]", "r[rho=0.5,dtype=int8]",
                                       "r[rho=1.0,dtype=float32]", "r[rho=1.0,dtype=int8]"]  # fmt: skip
    assert len({c.params for c in default_candidates()}) == len(default_candidates())


def test_autotune_on_a_route_chooses_under_the_budget(small_route: SyntheticRoute) -> None:
    r = small_route
    truth = np.arange(r.query.shape[0])
    cands = [Candidate(n, ModelParams.parse(trainer="ridge", rho=rho, dtype=dt))
             for n, rho, dt in (("big", 1.0, "float32"), ("mid", 0.5, "float32"),
                                ("small", 0.25, "int8"))]  # fmt: skip
    free = autotune(r.reference, r.query, truth, cands)
    sizes = {c.name: c.actual_bytes for c in free.candidates}
    assert sizes["small"] < sizes["mid"] < sizes["big"]
    budget = sizes["mid"]
    res = autotune(r.reference, r.query, truth, cands, budget_bytes=budget)
    assert res.chosen.actual_bytes <= budget and res.chosen.name in ("mid", "small")
    assert res.params == next(c.params for c in cands if c.name == res.chosen.name)
    easy = autotune(r.reference, r.query, truth, cands, target_precision=1e-9, tolerance=400)
    assert easy.chosen.name == "small" and "smallest" in easy.reason
    table = res.to_dict()
    assert table["chosen"] == res.chosen.name and len(table["candidates"]) == 3
    with pytest.raises(InvalidParameterError, match="no candidate fits"):
        autotune(r.reference, r.query, truth, cands, budget_bytes=1)
    with pytest.raises(InvalidParameterError, match="ground-truth"):
        autotune(r.reference, r.query, np.arange(r.query.shape[0] - 1), cands)

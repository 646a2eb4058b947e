"""Choosing a configuration by measurement on a validation split.

Every candidate (a name and its :class:`~service.encoding.factory.ModelParams`) is fitted on
the training rows and scored on validation queries whose places are known; then

* with ``budget_bytes``: the most precise candidate whose artifact (``footprint().actual_bytes``)
  fits the budget (ties: the smaller one);
* with ``target_precision``: the smallest candidate that reaches the target (within the budget
  when both are given); when none does, the most precise one within the budget, saying so;
* with neither: the most precise candidate.

The validation queries are whatever the caller passes and nothing else is looked at, so the
choice never sees test frames as long as the caller keeps them out (the API takes the split
explicitly). With ``sequence`` the validation queries are one drive in row order and the
sequence filter's precision is the objective instead of the single-frame one.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from service.encoding.base import precision_at
from service.encoding.factory import ModelParams, build_model
from service.encoding.sequence import SequenceConfig, sequence_localize
from service.errors import InvalidParameterError

# the small grids searched: the fields that set each preset's storage (robust has one digit,
# the whole route, so only its projection width; residue digits also shrink with Στ/N)
DEFAULT_GRID: dict[str, tuple[Any, ...]] = {"n_components": (64, 128, 256)}
RESIDUE_GRID: dict[str, tuple[Any, ...]] = {"code_ratio": (0.25, 0.5, 1.0)}
Progress = Callable[[str, int, int], None]


@dataclass(frozen=True)
class Candidate:
    name: str
    params: ModelParams


@dataclass(frozen=True)
class CandidateScore:
    name: str
    params: dict[str, Any]
    precision: float
    actual_bytes: int
    paper_bytes: float
    fit_seconds: float
    within_budget: bool
    reaches_target: bool | None  # None without a target


@dataclass(frozen=True)
class AutotuneResult:
    chosen: CandidateScore
    params: ModelParams
    candidates: list[CandidateScore]
    reason: str
    tolerance: int
    objective: str
    budget_bytes: int | None
    target_precision: float | None

    def to_dict(self) -> dict[str, Any]:
        return {
            "chosen": self.chosen.name, "reason": self.reason, "tolerance": self.tolerance,
            "objective": self.objective, "budget_bytes": self.budget_bytes,
            "target_precision": self.target_precision,
            "candidates": [asdict(c) for c in self.candidates],
        }  # fmt: skip


def grid_candidates(
    base: dict[str, ModelParams], grid: dict[str, tuple[Any, ...]] | None = None
) -> list[Candidate]:
    """Every base configuration at every combination of ``grid`` values (names say which);
    duplicates (a grid value equal to the base's) are kept once."""
    grid = DEFAULT_GRID if grid is None else grid
    out: dict[ModelParams, str] = {}
    for name, params in base.items():
        combos: list[dict[str, Any]] = [{}]
        for field, values in grid.items():
            combos = [{**c, field: v} for c in combos for v in values]
        for combo in combos:
            p = ModelParams.parse(**{**params.model_dump(), **combo})
            label = ",".join(f"{k}={v}" for k, v in combo.items())
            out.setdefault(p, f"{name}[{label}]" if label else name)
    return [Candidate(n, p) for p, n in out.items()]


def default_candidates() -> list[Candidate]:
    """The configurations ``gridplace train --budget-bytes/--target-precision`` searches: the
    ``robust`` preset over :data:`DEFAULT_GRID`, ``residue`` over :data:`RESIDUE_GRID` and the
    small ``ridge`` preset (the paper's ``logreg`` costs minutes per fit, so it is left out)."""
    robust = grid_candidates({"robust": ModelParams.parse(encoder_preset="robust")})
    residue = grid_candidates({"residue": ModelParams.parse(encoder_preset="residue")},
                              RESIDUE_GRID)  # fmt: skip
    return robust + residue + [Candidate("ridge", ModelParams.parse(encoder_preset="ridge"))]


def _fit(params: ModelParams, train: Any, places: np.ndarray | None) -> Any:
    model = build_model(params)
    if places is None:
        return model.fit(train)
    return model.fit(train, places=places)


def score_candidates(
    candidates: list[Candidate],
    train: Any,
    queries: np.ndarray,
    truth: np.ndarray,
    tolerance: int = 5,
    places: np.ndarray | None = None,
    sequence: SequenceConfig | None = None,
    progress: Progress | None = None,
) -> list[tuple[Candidate, float, int, float, float]]:
    """``(candidate, precision, actual bytes, paper bytes, fit seconds)`` of each candidate."""
    truth = np.asarray(truth, dtype=np.int64)
    if truth.shape != (queries.shape[0],):
        raise InvalidParameterError(
            f"{queries.shape[0]} validation queries but {truth.shape[0]} ground-truth indices"
        )
    rows = []
    for i, cand in enumerate(candidates):
        if progress is not None:
            progress(cand.name, i, len(candidates))
        start = time.perf_counter()
        model = _fit(cand.params, train, places)
        fit_s = time.perf_counter() - start
        if sequence is not None:
            pred = sequence_localize(model, queries, sequence).index
        else:
            pred = model.localize(queries).index
        fp = model.footprint()
        rows.append((cand, precision_at(pred, truth, tolerance), fp.actual_bytes,
                     fp.paper_bytes, fit_s))  # fmt: skip
    return rows


def select(
    scores: list[CandidateScore], budget_bytes: int | None, target_precision: float | None
) -> tuple[CandidateScore, str]:
    """The choice described in the module docstring, and why it was made."""
    if not scores:
        raise InvalidParameterError("no candidate configurations to choose from")
    fits = [s for s in scores if s.within_budget]
    if not fits:
        smallest = min(scores, key=lambda s: s.actual_bytes)
        raise InvalidParameterError(
            f"no candidate fits {budget_bytes} bytes; the smallest ({smallest.name}) needs "
            f"{smallest.actual_bytes} bytes"
        )
    best = max(fits, key=lambda s: (s.precision, -s.actual_bytes))
    budget = f" within {budget_bytes} bytes" if budget_bytes is not None else ""
    if target_precision is None:
        return best, f"most precise{budget} ({best.precision:.3f})"
    reach = [s for s in fits if s.reaches_target]
    if not reach:
        return best, (f"no candidate{budget} reaches {target_precision:.3f}; "
                      f"the most precise one ({best.precision:.3f}) was chosen")  # fmt: skip
    small = min(reach, key=lambda s: (s.actual_bytes, -s.precision))
    return small, f"smallest{budget} reaching {target_precision:.3f} ({small.precision:.3f})"


def autotune(
    train: Any,
    queries: np.ndarray,
    truth: np.ndarray,
    candidates: list[Candidate] | None = None,
    budget_bytes: int | None = None,
    target_precision: float | None = None,
    tolerance: int = 5,
    places: np.ndarray | None = None,
    sequence: SequenceConfig | None = None,
    progress: Progress | None = None,
) -> AutotuneResult:
    """Fit every candidate on ``train``, score it on the validation ``queries`` (query ``i``
    at place ``truth[i]``) and choose as the module docstring says."""
    if budget_bytes is not None and budget_bytes < 1:
        raise InvalidParameterError(f"the budget must be a positive byte count, got {budget_bytes}")
    if target_precision is not None and not 0.0 < target_precision <= 1.0:
        raise InvalidParameterError(
            f"the target precision must be in (0, 1], got {target_precision}"
        )
    if tolerance < 0:
        raise InvalidParameterError(f"the tolerance must be >= 0 frames, got {tolerance}")
    cands = default_candidates() if candidates is None else candidates
    raw = score_candidates(cands, train, queries, truth, tolerance, places, sequence, progress)
    scores = [
        CandidateScore(
            name=c.name, params=c.params.model_dump(mode="json"), precision=p, actual_bytes=b,
            paper_bytes=pb, fit_seconds=s,
            within_budget=budget_bytes is None or b <= budget_bytes,
            reaches_target=None if target_precision is None else p >= target_precision,
        )  # fmt: skip
        for c, p, b, pb, s in raw
    ]
    chosen, reason = select(scores, budget_bytes, target_precision)
    params = next(c.params for c in cands if c.name == chosen.name)
    return AutotuneResult(chosen, params, scores, reason, tolerance,
                          "sequence" if sequence is not None else "single",
                          budget_bytes, target_precision)  # fmt: skip

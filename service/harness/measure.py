"""Fitting and querying one model with wall-clock timing and precision at several tolerances."""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from service.encoding.base import Localization, precision_at
from service.harness.methods import MethodSpec, Recognizer

QUERY_BLOCK = 2000  # queries localised per call, bounding the decoder's working memory


@dataclass
class Fitted:
    spec: MethodSpec
    model: Recognizer
    train_seconds: float

    def footprint(self) -> dict[str, Any]:
        return self.model.footprint().to_dict()


def fit_timed(spec: MethodSpec, X: np.ndarray) -> Fitted:
    model = spec.build()
    start = time.perf_counter()
    model.fit(X)
    return Fitted(spec, model, time.perf_counter() - start)


def localize_timed(model: Recognizer, Q: np.ndarray) -> tuple[Localization, float]:
    """Localise ``Q`` in blocks; returns the answers and the total seconds."""
    parts: list[Localization] = []
    start = time.perf_counter()
    with np.errstate(divide="ignore"):  # log(0) of a zero confidence is -inf, as intended
        for s in range(0, Q.shape[0], QUERY_BLOCK):
            parts.append(model.localize(Q[s : s + QUERY_BLOCK]))
    elapsed = time.perf_counter() - start
    if len(parts) == 1:
        return parts[0], elapsed
    return (
        Localization(
            index=np.concatenate([p.index for p in parts]),
            confidence=np.concatenate([p.confidence for p in parts]),
            chunk=np.concatenate([p.chunk for p in parts]),
            log_score=np.concatenate([p.log_score for p in parts]),
        ),
        elapsed,
    )


def precisions(
    pred: np.ndarray, truth: np.ndarray, tolerances: tuple[int, ...]
) -> dict[str, float]:
    """``{"0": p, "5": p, …}``: precision within each frame tolerance."""
    return {str(t): precision_at(pred, truth, t) for t in tolerances}


def evaluate_condition(
    model: Recognizer, Q: np.ndarray, truth: np.ndarray, tolerances: tuple[int, ...]
) -> tuple[dict[str, Any], Localization]:
    """Precision at each tolerance and query timing on one query set."""
    loc, seconds = localize_timed(model, Q)
    out = {
        "n_queries": int(Q.shape[0]),
        "precision": precisions(loc.index, truth, tolerances),
        "query_seconds": seconds,
        "query_us_per_descriptor": 1e6 * seconds / max(1, Q.shape[0]),
    }
    return out, loc

"""Measuring a fitted model on queries with known places."""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from service.encoding.base import PlaceRecognizer, precision_at
from service.errors import InvalidInputError


def evaluate(
    model: PlaceRecognizer,
    queries: np.ndarray,
    ground_truth: np.ndarray | None = None,
    tolerance: int = 0,
    tolerances: tuple[int, ...] = (0, 1, 5, 10, 25),
) -> dict[str, Any]:
    """Precision within ``tolerance`` frames (and at several tolerances), timing, storage.

    ``ground_truth[i]`` is the reference frame of query ``i``; identity when omitted.
    """
    truth = np.arange(queries.shape[0]) if ground_truth is None else np.asarray(ground_truth)
    if truth.ndim != 1 or truth.shape[0] != queries.shape[0]:
        raise InvalidInputError(
            f"ground truth must hold one index per query ({queries.shape[0]}), got shape {truth.shape}"
        )
    if truth.dtype.kind not in "iu":
        raise InvalidInputError(f"ground truth must be integers, got dtype {truth.dtype}")
    start = time.perf_counter()
    loc = model.localize(queries)
    elapsed = time.perf_counter() - start
    fp = model.footprint()
    return {
        "precision": precision_at(loc.index, truth, tolerance),
        "tolerance": tolerance,
        "precision_at": {str(t): precision_at(loc.index, truth, t) for t in tolerances},
        "n": int(queries.shape[0]),
        "n_frames": model.n_frames_,
        "n_features": model.n_features_in_,
        "footprint_bytes": fp.actual_bytes,
        "paper_bytes": fp.paper_bytes,
        "footprint": fp.to_dict(),
        "mean_confidence": float(np.mean(loc.confidence)),
        "query_seconds_total": elapsed,
        "query_seconds_per_descriptor": elapsed / max(1, queries.shape[0]),
        "model": model.kind,
    }

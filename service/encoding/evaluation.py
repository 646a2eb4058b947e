"""Measuring a fitted model on queries with known places (single frames, and as a drive)."""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from service.encoding.adaptation import AdaptationConfig, adapt_drive
from service.encoding.base import PlaceRecognizer, precision_at
from service.encoding.sequence import SequenceConfig, sequence_localize
from service.errors import InvalidInputError

TOLERANCES: tuple[int, ...] = (0, 1, 2, 5, 10, 25)


def _truth(queries: np.ndarray, ground_truth: np.ndarray | None) -> np.ndarray:
    truth = np.arange(queries.shape[0]) if ground_truth is None else np.asarray(ground_truth)
    if truth.ndim != 1 or truth.shape[0] != queries.shape[0]:
        raise InvalidInputError(
            f"ground truth must hold one index per query ({queries.shape[0]}), got shape {truth.shape}"
        )
    if truth.dtype.kind not in "iu":
        raise InvalidInputError(f"ground truth must be integers, got dtype {truth.dtype}")
    return truth


def evaluate(
    model: PlaceRecognizer,
    queries: np.ndarray,
    ground_truth: np.ndarray | None = None,
    tolerance: int = 0,
    tolerances: tuple[int, ...] = TOLERANCES,
    sequence: SequenceConfig | None = None,
    adaptation: AdaptationConfig | None = None,
    odometry: Any = None,
) -> dict[str, Any]:
    """Precision within ``tolerance`` frames (and at several tolerances), timing, storage.

    ``ground_truth[i]`` is the reference frame of query ``i``; identity when omitted. With
    ``sequence``, the queries are also localized as one drive in row order through the sequence
    filter, adding ``sequence_precision``, ``sequence_precision_at`` and ``sequence`` (filter
    parameters, timing, mean confidence) to the answer. With ``adaptation`` the queries are
    first adapted as one camera's frames in row order (:mod:`service.encoding.adaptation`;
    the model must keep route statistics), for both measures; ``adaptation`` in the answer
    gives its parameters (``None``: not adapted).
    """
    truth = _truth(queries, ground_truth)
    if adaptation is not None:
        queries = adapt_drive(model, queries, adaptation)
    start = time.perf_counter()
    loc = model.localize(queries)
    elapsed = time.perf_counter() - start
    fp = model.footprint()
    out: dict[str, Any] = {
        "precision": precision_at(loc.index, truth, tolerance),
        "tolerance": tolerance,
        "precision_at": {str(t): precision_at(loc.index, truth, t) for t in tolerances},
        "n": int(queries.shape[0]),
        "n_frames": model.n_frames_,
        "n_features": model.n_features_in_,
        "footprint_bytes": fp.actual_bytes,
        # the paper's float64 formula (whole bytes); it describes the paper's mixed-radix code
        "paper_bytes": round(fp.paper_bytes),
        "exact_nn_uint8_bytes": int(model.n_frames_) * int(model.n_features_in_),
        "footprint": fp.to_dict(),
        "mean_confidence": float(np.mean(loc.confidence)),
        "query_seconds_total": elapsed,
        "query_seconds_per_descriptor": elapsed / max(1, queries.shape[0]),
        "model": model.kind,
        "adaptation": None if adaptation is None else adaptation.model_dump(),
    }
    if sequence is not None:
        out.update(evaluate_sequence(model, queries, truth, tolerance, tolerances, sequence,
                                     odometry))  # fmt: skip
    return out


def evaluate_sequence(
    model: PlaceRecognizer,
    queries: np.ndarray,
    ground_truth: np.ndarray | None = None,
    tolerance: int = 0,
    tolerances: tuple[int, ...] = TOLERANCES,
    config: SequenceConfig | None = None,
    odometry: Any = None,
) -> dict[str, Any]:
    """Precision of the sequence filter's estimates when ``queries`` are one drive in row
    order (the filter is causal: frame ``t``'s estimate uses frames ``≤ t`` only), with
    per-frame ``odometry`` (reference frames) when given."""
    truth = _truth(queries, ground_truth)
    config = config or SequenceConfig()
    start = time.perf_counter()
    track = sequence_localize(model, queries, config, odometry=odometry)
    elapsed = time.perf_counter() - start
    return {
        "sequence_precision": precision_at(track.index, truth, tolerance),
        "sequence_precision_at": {str(t): precision_at(track.index, truth, t) for t in tolerances},
        "sequence": {
            "filter": config.model_dump(),
            "mean_confidence": float(np.mean(track.confidence)),
            "seconds_total": elapsed,
            "seconds_per_frame": elapsed / max(1, queries.shape[0]),
        },
    }

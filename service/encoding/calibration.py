"""Temperature calibration: one scalar ``T`` per model, fitted on held-out queries.

Every digit classifier divides its scores by ``T`` before the log-softmax, so ``T`` sets how
peaked the frame scores are: what the sequence filter takes as emissions and what the
confidences mean. :func:`calibrate` chooses ``T`` by maximising the mean log-likelihood of the
true frame (the frame scores normalised over the route; within ``tolerance`` frames of the
truth when ``tolerance > 0``) on a validation split the caller passes explicitly, and stores
it in every classifier of the model (and saves with it). The argmax of a single query does
not depend on ``T``; only the scores and confidences do. Never pass the rows you report on.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from typing import Any

import numpy as np
from scipy.optimize import minimize_scalar
from scipy.special import logsumexp

from service.encoding.digit_classifier import DigitClassifier
from service.encoding.validation import check_descriptors
from service.errors import InvalidParameterError

_LOG_FLOOR = math.log(1e-12)  # a true frame outside the consulted chunks counts as this
_BOUNDS = (1e-4, 1e2)  # search range of T


def classifiers(model: Any) -> Iterator[DigitClassifier]:
    """Every digit classifier of a phase or chunked encoder (the chunk classifier too)."""
    encoders = getattr(model, "chunk_encoders_", None)
    if encoders is None:
        yield from model.digits_
        return
    yield model.chunk_classifier_
    for enc in encoders:
        yield from enc.digits_


def set_temperature(model: Any, temperature: float) -> None:
    """Store ``temperature`` in every classifier and in the model's parameters."""
    if not 0 < temperature < math.inf:
        raise InvalidParameterError(f"temperature must be > 0, got {temperature}")
    for dc in classifiers(model):
        dc.temperature = float(temperature)
    model.temperature = float(temperature)
    for part in (model, *getattr(model, "chunk_encoders_", [])):
        part.__dict__.pop("_serving_plan", None)  # scores changed: rebuild on next use
        part.__dict__.pop("_drive_scorer", None)
        if part is not model:
            part.temperature = float(temperature)


def log_likelihood(model: Any, X_val: np.ndarray, true_idx: np.ndarray, tolerance: int = 0) -> float:
    """Mean log-probability of the true frame (±``tolerance``) of every validation query."""
    scores = model.frame_log_scores(X_val)
    norm = logsumexp(scores, axis=1)
    frames = np.arange(scores.shape[1])
    near = np.abs(frames[None, :] - true_idx[:, None]) <= tolerance
    hit = logsumexp(np.where(near, scores, -np.inf), axis=1)
    ll = np.where(np.isfinite(hit), hit - norm, _LOG_FLOOR)
    return float(np.maximum(ll, _LOG_FLOOR).mean())


def calibrate(
    model: Any, X_val: Any, true_idx: Any, tolerance: int = 0, xatol: float = 1e-3
) -> float:
    """Fit, store and return the temperature of a fitted ``model`` on the validation queries
    ``X_val`` whose true frames are ``true_idx`` (a split the caller holds out)."""
    model._check_fitted()
    Q = check_descriptors(X_val, n_features=model.n_features_in_, what="validation queries")
    truth = np.asarray(true_idx, dtype=np.int64)
    if truth.shape != (Q.shape[0],):
        raise InvalidParameterError(f"{Q.shape[0]} validation queries but {truth.size} true frames")
    if truth.size and (truth.min() < 0 or truth.max() >= model.n_frames_):
        raise InvalidParameterError(f"true frames must lie in [0, {model.n_frames_})")
    if int(tolerance) < 0:
        raise InvalidParameterError(f"tolerance must be >= 0, got {tolerance}")

    def loss(log_t: float) -> float:
        set_temperature(model, math.exp(log_t))
        return -log_likelihood(model, Q, truth, int(tolerance))

    lo, hi = (math.log(b) for b in _BOUNDS)
    res = minimize_scalar(loss, bounds=(lo, hi), method="bounded", options={"xatol": xatol})
    best = float(math.exp(res.x))
    set_temperature(model, best)
    return best

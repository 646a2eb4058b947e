"""Turning per-encoder class scores into a frame index.

Scores of each encoder become log-probabilities (a log-softmax over its classes). Two modes:

- ``argmax``: the paper's rule, each digit independently; an index that falls outside the
  route (possible when ``∏τ > N``) is decoded jointly instead.
- ``joint``: beam search over the digits, most significant first, adding the encoders'
  log-probabilities and pruning every prefix whose smallest completion is ``≥ N``. With a
  beam at least as wide as the number of prefixes it is exact.

Every decode returns the joint log-probability of the chosen digits; ``exp`` of it is the
confidence a caller can threshold to reject queries.

The estimators answer through the exact, vectorised decoder of
:mod:`service.encoding.serving_plan`; this module is the reference it is tested and
benchmarked against (:func:`reference_localize`: per-chunk loops and a beam per digit).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from scipy.special import log_softmax

from service.encoding.phases import place_values
from service.errors import InvalidParameterError

DECODE_MODES: tuple[str, ...] = ("argmax", "joint")


def log_probabilities(scores: np.ndarray) -> np.ndarray:
    """Row-wise log-softmax; classes with score −inf get log-probability −inf."""
    with np.errstate(invalid="ignore"):
        return log_softmax(scores, axis=1)


def decode(
    logps: Sequence[np.ndarray],
    periods: Sequence[int],
    n_valid: int,
    mode: str = "joint",
    beam_width: int = 64,
) -> tuple[np.ndarray, np.ndarray]:
    """Decode per-encoder log-probabilities into ``(indices, log_scores)``."""
    if mode not in DECODE_MODES:
        raise InvalidParameterError(f"unknown decode mode {mode!r}; choose one of {DECODE_MODES}")
    if mode == "joint":
        return joint_decode(logps, periods, n_valid, beam_width)
    digits = np.stack([lp.argmax(axis=1) for lp in logps], axis=1)
    index = digits @ place_values(periods)
    score = np.sum([lp[np.arange(lp.shape[0]), digits[:, j]] for j, lp in enumerate(logps)], axis=0)
    outside = np.flatnonzero(index >= n_valid)
    if outside.size:
        sub = [lp[outside] for lp in logps]
        index[outside], score[outside] = joint_decode(sub, periods, n_valid, beam_width)
    return index.astype(np.int64), np.asarray(score, dtype=np.float64)


def joint_decode(
    logps: Sequence[np.ndarray], periods: Sequence[int], n_valid: int, beam_width: int = 64
) -> tuple[np.ndarray, np.ndarray]:
    """Beam search over digits restricted to indices ``< n_valid``."""
    if beam_width < 1:
        raise InvalidParameterError(f"beam_width must be >= 1, got {beam_width}")
    n_q = logps[0].shape[0]
    vals = place_values(periods)
    prefix = np.zeros((n_q, 1), dtype=np.int64)
    score = np.zeros((n_q, 1), dtype=np.float64)
    rows = np.arange(n_q)[:, None]
    for j, lp in enumerate(logps):
        tau = lp.shape[1]
        cand_idx = (prefix[:, :, None] + np.arange(tau, dtype=np.int64)[None, None, :] * vals[j])
        cand_score = score[:, :, None] + lp[:, None, :]
        cand_idx = cand_idx.reshape(n_q, -1)
        cand_score = np.where(cand_idx < n_valid, cand_score.reshape(n_q, -1), -np.inf)
        width = min(beam_width, cand_idx.shape[1])
        if width < cand_idx.shape[1]:
            keep = np.argpartition(-cand_score, width - 1, axis=1)[:, :width]
        else:
            keep = np.broadcast_to(np.arange(width), (n_q, width))
        prefix = cand_idx[rows, keep]
        score = cand_score[rows, keep]
    best = np.argmax(score, axis=1)
    return prefix[np.arange(n_q), best], score[np.arange(n_q), best]


def reference_localize(model: Any, Q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(index, chunk, log_score)`` of a phase or chunked encoder by the reference decoder:
    float64 scores, :func:`decode` (the model's ``decode`` mode and ``beam_width``) per
    chunk, and the best of the ``top_chunks`` chunks by joint log-probability."""
    encoders = getattr(model, "chunk_encoders_", None)
    if encoders is None:
        norm = model.normalizer_
        index, score = model._decode_normalised(Q if norm is None else norm.transform(Q))
        return index, np.zeros_like(index), score
    Qn = model.normalizer_.transform(Q)
    n_q = Qn.shape[0]
    chunk_lp = model.chunk_classifier_.log_probs(Qn)
    m = min(int(model.top_chunks), len(encoders))
    top = np.argsort(-chunk_lp, axis=1, kind="stable")[:, :m]
    best_score = np.full(n_q, -np.inf)
    best_index = np.zeros(n_q, dtype=np.int64)
    best_chunk = np.zeros(n_q, dtype=np.int64)
    for rank in range(m):
        for c in np.unique(top[:, rank]):
            rows = np.flatnonzero(top[:, rank] == c)
            local, score = encoders[c]._decode_normalised(Qn[rows])
            score = score + chunk_lp[rows, c]
            better = score > best_score[rows]
            upd = rows[better]
            best_score[upd] = score[better]
            best_index[upd] = local[better] + model.chunk_bounds_[c]
            best_chunk[upd] = c
    return best_index, best_chunk, best_score

"""Exact decoding of digit log-probabilities into frame indices, vectorised over queries.

A candidate frame ``f`` scores ``Σ_j lp_j[label_j(f)]``. For the mixed-radix labelling of
:mod:`service.encoding.phases` no search is needed: the best of *all* ``∏τ`` codes is the
per-digit argmax (``O(Στ)`` per query); when that code is not a frame of the route
(``≥ N``, possible when ``∏τ > N``), the best valid code is found among ``k + 1`` boxes that
tile ``[0, N)``: the first ``j`` digits equal those of ``N − 1``, digit ``j`` is smaller, the
rest are free (best = per-digit maxima), plus ``N − 1`` itself. Both are exact, unlike a beam.

Arrays here are stacked over *pairs* (a query and one candidate chunk) and padded: ``lp`` is
``(P, k, τ_max)`` with ``−inf`` beyond a digit's own period, so padding never wins.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class FreeDecode:
    """Per-digit maxima of each pair: the best of all codes, valid or not."""

    digits: np.ndarray  # (P, k) int64 argmax of every digit
    best: np.ndarray  # (P,) Σ_j max lp_j: an upper bound of the best valid frame's score
    gaps: np.ndarray  # (P, k) top-1 − top-2 score of every digit (inf: a single class)
    top: np.ndarray  # (P, k) top score of every digit
    log_norm: np.ndarray  # (P, k) log Σ_c exp(s_c − top): lp = s − top − log_norm

    def subset(self, rows: np.ndarray) -> FreeDecode:
        return FreeDecode(self.digits[rows], self.best[rows], self.gaps[rows],
                          self.top[rows], self.log_norm[rows])  # fmt: skip

    def log_probs(self, S: np.ndarray, rows: np.ndarray) -> np.ndarray:
        """Log-softmax of the raw scores ``S`` of some pairs, ``(len(rows), k, width)``."""
        return (S[rows] - self.top[rows, :, None]) - self.log_norm[rows, :, None]


def log_softmax_last(S: np.ndarray) -> np.ndarray:
    """Log-softmax over the last axis (scipy's formula; ``−inf`` entries stay ``−inf``)."""
    tmp = S - S.max(axis=-1, keepdims=True)
    return tmp - np.log(np.exp(tmp).sum(axis=-1, keepdims=True))


def top_two(S: np.ndarray, digits: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The largest and second-largest of ``S (P, k, width)`` along its last axis, given its
    argmax ``digits``: the maximum with each argmax masked (a tie keeps its value; a single
    class has no runner-up, ``−inf``). Two passes, where a partition over a route's ``N``
    scores costs about ten times as much."""
    if S.shape[2] < 2:
        return S[:, :, 0], np.full(S.shape[:2], -np.inf)
    at = digits[:, :, None]
    top = np.take_along_axis(S, at, axis=2)[:, :, 0]
    rest = S.copy()
    np.put_along_axis(rest, at, -np.inf, axis=2)
    return top, rest.max(axis=2)


def free_decode(S: np.ndarray, padded: bool = False) -> FreeDecode:
    """Argmax of every digit of raw scores ``S (P, k, width)``, the summed log-probability
    of those digits and every digit's runner-up gap (``padded``: some digits are all −inf)."""
    digits = S.argmax(axis=2)
    top, second = top_two(S, digits)
    if padded:  # a missing digit (all −inf) adds 0 and has no runner-up
        missing = np.isneginf(top)
        top, second = np.where(missing, 0.0, top), np.where(missing, -np.inf, second)
        with np.errstate(divide="ignore"):
            log_norm = np.where(missing, 0.0, np.log(np.exp(S - top[:, :, None]).sum(axis=2)))
    else:
        log_norm = np.log(np.add.reduce(np.exp(S - top[:, :, None]), axis=2))
    return FreeDecode(digits, -np.add.reduce(log_norm, axis=1), top - second, top, log_norm)


def constrained_decode(
    lp: np.ndarray, free: FreeDecode, last: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Best code ``≤`` the mixed-radix digits ``last`` (those of ``N − 1``) of every pair.

    Returns ``(digits (P, k), score (P,))``. Box ``j`` fixes digits ``< j`` to ``last``,
    digit ``j`` below ``last[j]`` and frees the rest; the last candidate is ``last`` itself.
    """
    n_p, k, width = lp.shape
    rows = np.arange(n_p)
    best_d = -free.log_norm  # lp of every digit's argmax
    suffix = np.concatenate([np.cumsum(best_d[:, ::-1], axis=1)[:, ::-1][:, 1:],
                             np.zeros((n_p, 1))], axis=1)  # fmt: skip
    on_last = lp[rows[:, None], np.arange(k)[None, :], last]  # (P, k) lp of N−1's digits
    prefix = np.concatenate([np.zeros((n_p, 1)), np.cumsum(on_last, axis=1)], axis=1)
    scores = np.empty((n_p, k + 1))
    cands = np.empty((n_p, k + 1, k), dtype=np.int64)
    below = np.arange(width)[None, :] < last[:, :, None]  # (P, k, width)
    restricted = np.where(below, lp, -np.inf)
    arg = restricted.argmax(axis=2)  # (P, k)
    top = np.take_along_axis(restricted, arg[:, :, None], axis=2)[:, :, 0]
    for j in range(k):
        scores[:, j] = prefix[:, j] + top[:, j] + suffix[:, j]
        cands[:, j, :j] = last[:, :j]
        cands[:, j, j] = arg[:, j]
        cands[:, j, j + 1 :] = free.digits[:, j + 1 :]
    scores[:, k] = prefix[:, k]
    cands[:, k, :] = last
    pick = scores.argmax(axis=1)
    return cands[rows, pick], scores[rows, pick]


def table_decode(lp: np.ndarray, labels: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Enumerate the frames of an arbitrary label table ``(N, k)``: ``(index, best, second)``."""
    scores = frame_scores_table(lp, labels)
    index = scores.argmax(axis=1)
    best = scores[np.arange(scores.shape[0]), index]
    if scores.shape[1] >= 2:
        second = np.partition(scores, scores.shape[1] - 2, axis=1)[:, -2]
    else:
        second = np.full(scores.shape[0], -np.inf)
    return index.astype(np.int64), best, second


def frame_scores_mixed_radix(lp: np.ndarray, periods: tuple[int, ...], n_frames: int) -> np.ndarray:
    """``(P, N)`` scores of every frame: the outer sum of the digits' log-probabilities."""
    out = lp[:, 0, : periods[0]]
    for j in range(1, len(periods)):
        out = (out[:, :, None] + lp[:, j, None, : periods[j]]).reshape(lp.shape[0], -1)
    return out[:, :n_frames]


def frame_scores_table(lp: np.ndarray, labels: np.ndarray) -> np.ndarray:
    """``(P, N)`` scores of every frame of a label table ``(N, k)``."""
    out = np.zeros((lp.shape[0], labels.shape[0]))
    for j in range(labels.shape[1]):
        out += lp[:, j, labels[:, j]]
    return out


def frame_scores_residue(lp: np.ndarray, periods: tuple[int, ...], n_frames: int) -> np.ndarray:
    """``(P, N)`` scores of every frame labelled ``f mod τ_j``: :func:`frame_scores_table` of
    that table (the same sums in the same order), without the ``(N, k)`` table."""
    out = np.zeros((lp.shape[0], n_frames))
    for j, t in enumerate(periods):
        out += np.tile(lp[:, j, :t], (1, -(-n_frames // t)))[:, :n_frames]
    return out

"""Exact decoding of a residue code without scoring every frame of the route.

A residue code labels frame ``f`` with its digits ``f mod τ_j``; a frame scores
``Σ_j lp_j[f mod τ_j]``. Enumerating the route (:func:`~service.encoding.exact_decode.table_decode`)
costs ``O(k·N)`` per query, which on a long route is the whole cost of a query. The frames
of one class ``c`` of the *pivot* digit (the one with the longest period, ``τ*``) are
``c, c + τ*, c + 2τ*, …``: ``⌈N / τ*⌉`` of them, all bounded above by that class's own
log-probability plus every other digit's maximum. So the best frame is found by scoring the
frames of the classes whose bound can still reach it — branch and bound over ``τ*`` classes:

1. score the frames of the ``first`` classes of highest bound;
2. score the frames of every other class whose bound reaches the best score found, less
   ``margin`` (the caller's certification margin: what makes its runner-up test exact).

Every frame left out scores strictly below ``best − margin``, so the answer, its score and
the verdict ``best − second > margin`` are those of the full enumeration (the same sums in
the same order, and floating-point addition is monotone, so a bound summed in that order
is never below a frame's own sum). A flat, uninformative query reads more classes; a
confident one a few.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

#: classes of the pivot digit scored before the bound is first applied
FIRST_CLASSES = 32


def is_residue_table(labels: np.ndarray, periods: Sequence[int]) -> bool:
    """Whether the label table ``(N, k)`` is ``f mod τ_j`` for every frame and digit."""
    n = labels.shape[0]
    if labels.shape[1] != len(periods) or min(periods, default=0) < 1:
        return False
    frames = np.arange(n, dtype=np.int64)
    return all(np.array_equal(labels[:, j], frames % int(t)) for j, t in enumerate(periods))


def residue_decode(
    lp: np.ndarray, periods: Sequence[int], n_frames: int, margin: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(index, best, second)`` of every row of ``lp`` ``(P, k, width)`` (digit ``j``'s
    log-probabilities in ``lp[:, j, :τ_j]``) over frames ``0 … n_frames − 1`` labelled
    ``f mod τ_j``. ``index`` and ``best`` equal the full enumeration's (the lowest frame on
    ties); ``second`` is the runner-up among the frames scored, which decides
    ``best − second > margin`` as the true runner-up would (``margin`` ≥ 0 per row; 0 when
    omitted)."""
    tau = [int(t) for t in periods]
    n_rows = lp.shape[0]
    pad = np.zeros(n_rows) if margin is None else np.maximum(np.asarray(margin, float), 0.0)
    index = np.zeros(n_rows, dtype=np.int64)
    best = np.full(n_rows, -np.inf)
    second = np.full(n_rows, -np.inf)
    pivot = int(np.argmax(tau))
    steps = np.arange(-(-n_frames // tau[pivot]), dtype=np.int64) * tau[pivot]
    for r in range(n_rows):
        digits = [lp[r, j, : tau[j]] for j in range(len(tau))]
        bound = np.zeros(tau[pivot])
        for j, d in enumerate(digits):  # the frames' own order of summation
            bound = bound + (d if j == pivot else d.max())
        first = _top(bound, FIRST_CLASSES)
        f, s = _frames_of(first, steps, n_frames, digits, tau)
        rest = np.flatnonzero(bound >= _best(s)[1] - pad[r])
        rest = np.setdiff1d(rest, first, assume_unique=True)
        if rest.size:
            f2, s2 = _frames_of(rest, steps, n_frames, digits, tau)
            f, s = np.concatenate([f, f2]), np.concatenate([s, s2])
        index[r], best[r], second[r] = _winner(f, s)
    return index, best, second


def _top(bound: np.ndarray, m: int) -> np.ndarray:
    if bound.size <= m:
        return np.arange(bound.size)
    return np.argpartition(-bound, m - 1)[:m]


def _frames_of(classes: np.ndarray, steps: np.ndarray, n_frames: int,
               digits: list[np.ndarray], tau: list[int]) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """Every frame of the pivot's ``classes`` and its score ``Σ_j lp_j[f mod τ_j]``."""
    f = (classes.astype(np.int64)[:, None] + steps[None, :]).ravel()
    f = f[f < n_frames]
    s = np.zeros(f.size)
    for j, d in enumerate(digits):
        s = s + d[f % tau[j]]
    return f, s


def _best(s: np.ndarray) -> tuple[int, float]:
    if s.size == 0:
        return -1, -np.inf
    i = int(np.argmax(s))
    return i, float(s[i])


def _winner(f: np.ndarray, s: np.ndarray) -> tuple[int, float, float]:
    """The lowest frame of the best score, that score, and the runner-up score."""
    if s.size == 0:
        return 0, -np.inf, -np.inf
    top = float(s.max())
    win = int(f[s == top].min())
    second = float(np.partition(s, s.size - 2)[-2]) if s.size >= 2 else -np.inf
    return win, top, second

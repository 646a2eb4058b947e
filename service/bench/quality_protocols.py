"""The evaluation protocols of ``gridplace bench quality``: which rows train, which query.

A route has ``N`` places, a reference traversal (row i = place i) and a query traversal
whose row ``j`` lies at place ``truth[j]``. Queries are split by row order into half
**A** (the first 50 % of the drive: validation, the only rows any tuning may look at) and
half **B** (the rest: test); the whole drive is reported too.

* ``cross`` (protocol a): train on the reference traversal, query the other traversal;
  report A (validation), B (test) and the whole drive, each as its own drive for the
  sequence filter.
* ``multi`` (protocol b): train on the reference traversal plus the query traversal's half
  A (each row labelled with its place), query half B; then swap the halves. Each fold tests
  only on rows it never trained on; ``all`` pools both folds' test rows.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from service.errors import InvalidParameterError

PROTOCOLS: tuple[str, ...] = ("cross", "multi")
PROTOCOL_LABELS = {
    "cross": "(a) reference traversal → query traversal",
    "multi": "(b) multi-traversal: reference + half of the query traversal → the other half",
}


@dataclass(frozen=True)
class Fold:
    """One training set and the query drives measured on the model it trains."""

    name: str
    train_rows: np.ndarray  # (n_train, d) descriptors
    train_places: np.ndarray | None  # place of each training row; None = row i is place i
    drives: dict[str, np.ndarray]  # drive name → query row indices, in driving order
    tuned_on: str  # which rows a setting may be tuned on, in words


def query_halves(n_queries: int) -> dict[str, np.ndarray]:
    """Rows of half A (validation), half B (test) and the whole drive."""
    if n_queries < 2:
        raise InvalidParameterError(f"need at least 2 queries to split, got {n_queries}")
    cut = n_queries // 2
    rows = np.arange(n_queries)
    return {"A": rows[:cut], "B": rows[cut:], "all": rows}


def cross_folds(reference: np.ndarray, n_queries: int) -> list[Fold]:
    halves = query_halves(n_queries)
    return [Fold("reference", reference, None, halves, "A (validation)")]


def multi_folds(reference: np.ndarray, query: np.ndarray, truth: np.ndarray) -> list[Fold]:
    """Train on the reference + query half A, test half B; and the other way round."""
    halves = query_halves(query.shape[0])
    ref_places = np.arange(reference.shape[0], dtype=np.int64)
    folds = []
    for train_half, test_half in (("A", "B"), ("B", "A")):
        rows = halves[train_half]
        folds.append(Fold(
            f"train reference+{train_half}, test {test_half}",
            np.concatenate([reference, query[rows]]),
            np.concatenate([ref_places, truth[rows].astype(np.int64)]),
            {test_half: halves[test_half]},
            f"nothing (a fold never tunes; its test half {test_half} is unseen)",
        ))  # fmt: skip
    return folds


def folds_for(
    protocol: str, reference: np.ndarray, query: np.ndarray, truth: np.ndarray
) -> list[Fold]:
    if protocol == "cross":
        return cross_folds(reference, query.shape[0])
    if protocol == "multi":
        return multi_folds(reference, query, truth)
    raise InvalidParameterError(f"unknown protocol {protocol!r}; choose from {PROTOCOLS}")

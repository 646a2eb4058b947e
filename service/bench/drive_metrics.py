"""What ``gridplace bench drive`` reports of the tracks it gets: precision within ``±tol``
frames (with a bootstrap interval over the drives: which 30 drives a seed draws moves a figure
by two points or more), precision after ``L`` frames over many short drives and the
first ``L`` that reaches a target (``L90``), and the frames a kidnapped vehicle takes to be
found again."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

TOLERANCE = 5  # frames either side counted as correct
TARGET = 0.9  # the precision that L90 waits for
HOLD = 20  # a recovered track stays within the tolerance this many frames
BOOTSTRAP = 2000  # resamples of the drives for a precision's interval


def correct(pred: np.ndarray, truth: np.ndarray, tol: int = TOLERANCE) -> np.ndarray:
    return np.abs(np.asarray(pred, np.int64) - np.asarray(truth, np.int64)) <= tol


def precision(preds: Sequence[np.ndarray], truths: Sequence[np.ndarray],
              tol: int = TOLERANCE) -> float:  # fmt: skip
    """Share of all frames of all drives within ``±tol`` (drives pooled by frames)."""
    hits, frames = _per_drive(preds, truths, tol)
    return float(hits.sum() / frames.sum()) if frames.sum() else float("nan")


def _per_drive(preds: Sequence[np.ndarray], truths: Sequence[np.ndarray],
               tol: int) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """Each drive's frames within ``±tol`` and its frames, as float64 arrays."""
    hits = [int(correct(p, t, tol).sum()) for p, t in zip(preds, truths, strict=True)]
    frames = [int(np.asarray(t).size) for t in truths]
    return np.array(hits, dtype=np.float64), np.array(frames, dtype=np.float64)


def precision_interval(preds: Sequence[np.ndarray], truths: Sequence[np.ndarray],
                       level: float = 0.95, resamples: int = BOOTSTRAP, seed: int = 0,
                       tol: int = TOLERANCE) -> tuple[float, float] | None:  # fmt: skip
    """A percentile bootstrap interval of :func:`precision` that resamples whole drives (frames
    of one drive are not independent); ``None`` for fewer than two drives."""
    if len(truths) < 2:
        return None
    hits, frames = _per_drive(preds, truths, tol)
    pick = np.random.default_rng(seed).integers(0, len(truths), size=(resamples, len(truths)))
    with np.errstate(invalid="ignore", divide="ignore"):
        boot = hits[pick].sum(axis=1) / frames[pick].sum(axis=1)
    boot = boot[np.isfinite(boot)]
    if boot.size == 0:
        return None
    alpha = 0.5 * (1.0 - level)
    lo, hi = np.quantile(boot, [alpha, 1.0 - alpha])
    return float(lo), float(hi)


def precision_after(preds: Sequence[np.ndarray], truths: Sequence[np.ndarray],
                    tol: int = TOLERANCE) -> np.ndarray:  # fmt: skip
    """``out[L − 1]``: share of drives whose estimate at their ``L``-th frame is within
    ``±tol`` (drives of equal length)."""
    return np.mean([correct(p, t, tol) for p, t in zip(preds, truths, strict=True)], axis=0)


def first_reaching(curve: np.ndarray, target: float = TARGET) -> int | None:
    """The first ``L`` (1-based) with ``curve[L − 1] ≥ target``; ``None`` if none does."""
    hits = np.flatnonzero(np.asarray(curve) >= target)
    return int(hits[0]) + 1 if hits.size else None


def recovery(pred: np.ndarray, truth: np.ndarray, event: int, tol: int = TOLERANCE,
             hold: int = HOLD) -> int | None:  # fmt: skip
    """Frames after the jump at ``event`` until the estimate is within ``±tol`` and stays
    there for ``hold`` frames (or to the end of the drive, if that comes first); 0: right at
    the first frame after the jump. ``None``: never within the drive."""
    ok = correct(pred[event:], truth[event:], tol)
    n = ok.size
    if n == 0:
        return None
    # run[k]: frames in a row that are correct from k on
    run = np.zeros(n + 1, dtype=np.int64)
    for k in range(n - 1, -1, -1):
        run[k] = run[k + 1] + 1 if ok[k] else 0
    good = np.flatnonzero(run[:n] >= np.minimum(hold, n - np.arange(n)))
    return int(good[0]) if good.size else None


def recovery_summary(frames: Sequence[int | None]) -> dict[str, Any]:
    """Median and 90th percentile of the recovered drives' frames, and the share never
    recovered."""
    found = np.array([f for f in frames if f is not None], dtype=np.float64)
    return {
        "drives": len(frames),
        "median": float(np.median(found)) if found.size else None,
        "p90": float(np.percentile(found, 90)) if found.size else None,
        "never": (len(frames) - found.size) / len(frames) if frames else None,
    }

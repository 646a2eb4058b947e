"""One step of appearance adaptation for a group of drives (:mod:`service.encoding.adaptation`):
the robust exponentially weighted update of each drive's running mean and variance, in
float32, vectorised over the drives that share route statistics and configuration."""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from service.encoding.adaptation import AdaptationConfig, AppearanceAdapter, RouteStatistics

MEAN, VAR, LAST = 0, 1, 2  # rows of an adapter's state
MIN_SCALE_RATIO = 0.01  # √v is never taken below this fraction of the route's σ


def step(route: RouteStatistics, config: AdaptationConfig, state: np.ndarray, X: np.ndarray,
          adapters: Sequence[AppearanceAdapter]) -> np.ndarray:  # fmt: skip
    """One frame of each of ``k`` distinct drives: ``state`` (k, 3, d) holds their statistics
    (updated in place), ``X`` (k, d) their frames; the adapted frames are returned and each
    adapter's counters move on (its state array is the caller's to write back). float32
    throughout, with as few passes over the columns as the rule allows: the step is
    memory-bound (three times faster than in float64 for a fleet's batch at d = 2,048)."""
    mean, var, last = state[:, MEAN], state[:, VAR], state[:, LAST]
    d = X.shape[1]
    with np.errstate(over="ignore", invalid="ignore"):  # a wild frame's z² may overflow: inf
        z = X - mean  # δ, then the z-score in place
        root = np.maximum(var, route.floor)
        np.sqrt(root, out=root)  # the standard deviation a column is divided by
        z /= root
        out = z * route.scale
        out += route.mean
        inside = np.vecdot(z, z) <= config.outlier * d  # mean z² ≤ outlier; False for inf, NaN
        novel = inside
        if config.novelty > 0 and inside.any():
            diff = X - last
            diff /= root
            novel = inside & ~(np.vecdot(diff, diff) < config.novelty * d)
    learn: list[int] = []
    anchor: list[int] = []
    for i, a in enumerate(adapters):
        a._frames += 1
        if not inside[i]:
            a._outliers += 1
            a._run += 1
            if a._run >= config.patience:
                anchor.append(i)
                a._run = 0
            continue
        a._run = 0
        if novel[i] or not a._has_last:
            learn.append(i)
            a._learnt += 1
            a._has_last = True
            a._seed_weight *= 1.0 - config.alpha
    if learn:
        step = z
        if not inside.all():
            step[~inside] = 0.0  # an outlier's z may be infinite: it is not learnt from anyway
        np.clip(step, -config.clip, config.clip, out=step)
        step *= root  # δ, each column clipped at ±clip standard deviations
        alpha, keep = np.float32(config.alpha), np.float32(1.0 - config.alpha)  # one rounding
        if len(learn) == len(adapters):
            gain = step * alpha
            mean += gain  # exponentially weighted mean and variance
            gain *= step  # α·δ²
            var += gain
            var *= keep  # (1 − α)(v + α·δ²), West (1979)
            last[...] = X
        else:  # rows that are not learnt from get a zero step and a factor 1: exactly unchanged
            learns = np.zeros((len(adapters), 1), dtype=bool)
            learns[learn] = True
            gain = step * np.where(learns, alpha, np.float32(0.0))
            mean += gain
            gain *= step
            var += gain
            var *= np.where(learns, keep, np.float32(1.0))
            np.copyto(last, X, where=learns)
    anchor = [i for i in anchor if np.isfinite(X[i]).all()]  # never restart at an infinity
    if anchor:  # the drive moved away for good: start over from this frame, the route's spread
        mean[anchor] = X[anchor]
        var[anchor] = route.var
        last[anchor] = X[anchor]
        for i in anchor:
            adapters[i]._has_last = True
            adapters[i]._seed_weight = 0.0
    return out

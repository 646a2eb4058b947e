"""Sequence filtering (beyond the paper): stabilise a vehicle's estimate with its recent frames.

In the spirit of SeqSLAM, a vehicle driving the route visits reference frames in order at some
unknown speed ``v`` (reference frames per query frame). Each query gives a log-probability for
every frame of the route (:meth:`PhaseEncoder.frame_log_scores`); the filter keeps the last
``window`` of them and scores each current position ``i`` and speed ``v`` by
``Σ_s L_{t−s}(i − v·s)``, so a position is believed when the recent frames agree along a
straight trajectory ending there. Frames whose own evidence contradicts the trajectory cannot
make the estimate jump across the route on their own.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np
from scipy.special import logsumexp

from service.errors import InvalidParameterError

_FLOOR = np.log(1e-9)  # a frame's vote for an index it finds impossible, so one frame cannot veto


@dataclass(frozen=True)
class SequenceConfig:
    window: int = 6  # query frames combined (1 = no filtering)
    min_velocity: float = 0.0  # reference frames advanced per query frame
    max_velocity: float = 2.0
    n_velocities: int = 9
    reverse: bool = False  # also consider driving the route backwards

    def velocities(self) -> np.ndarray:
        if self.window < 1 or self.n_velocities < 1 or self.max_velocity < self.min_velocity:
            raise InvalidParameterError("invalid sequence filter configuration")
        v = np.linspace(self.min_velocity, self.max_velocity, self.n_velocities)
        return np.unique(np.concatenate([v, -v])) if self.reverse else v


@dataclass(frozen=True)
class SequenceEstimate:
    index: int
    confidence: float
    log_score: float
    frames_used: int  # how many recent frames supported this estimate


class SequenceFilter:
    """State of one vehicle's stream over one route of ``n_frames`` frames."""

    def __init__(self, n_frames: int, config: SequenceConfig | None = None) -> None:
        self.n_frames = int(n_frames)
        self.config = config or SequenceConfig()
        self._velocities = self.config.velocities()
        self._history: deque[np.ndarray] = deque(maxlen=self.config.window)

    def reset(self) -> None:
        self._history.clear()

    def update(self, frame_log_scores: np.ndarray) -> SequenceEstimate:
        """Add one query's per-frame log-scores ``(N,)`` and return the filtered estimate."""
        scores = np.asarray(frame_log_scores, dtype=np.float64)
        if scores.shape != (self.n_frames,):
            raise InvalidParameterError(
                f"expected {self.n_frames} frame scores, got shape {scores.shape}"
            )
        if not np.isfinite(scores).any():
            raise InvalidParameterError("every frame score is -inf")
        posterior = scores - logsumexp(scores)
        self._history.appendleft(np.maximum(posterior, _FLOOR))  # newest first
        positions = np.arange(self.n_frames)
        best_total = np.full(self.n_frames, -np.inf)
        for v in self._velocities:
            total = np.zeros(self.n_frames)
            for s, past in enumerate(self._history):
                idx = np.rint(positions - v * s).astype(np.int64)
                inside = (idx >= 0) & (idx < self.n_frames)
                total += np.where(inside, past[np.clip(idx, 0, self.n_frames - 1)], _FLOOR)
            np.maximum(best_total, total, out=best_total)
        best = int(np.argmax(best_total))
        log_conf = float(best_total[best] - logsumexp(best_total))
        return SequenceEstimate(best, float(np.exp(log_conf)), log_conf, len(self._history))

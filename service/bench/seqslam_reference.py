"""The SeqSLAM-style window filter the service streamed with before the recursive Bayes filter
of :mod:`service.encoding.sequence`. It is the benchmark's reference (its cost and precision
beside the HMM's in one run, ``gridplace bench sequence``); it measured worse on every
validation drive and is not served.

In the spirit of SeqSLAM, a vehicle visits reference frames in order at some speed ``v``
(reference frames per query frame). The filter keeps the last ``window`` queries' frame
log-posteriors and scores each current position ``i`` and grid speed ``v`` by
``Σ_s L_{t−s}(i − v·s)``: a position is believed when the recent frames agree along a
straight trajectory ending there. Each update re-scans the whole window at every speed, so it
costs ``O(window · S · N)`` per frame (the HMM filter costs ``O(S · N)``).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np
from scipy.special import logsumexp

from service.encoding.sequence import SequenceEstimate, SequenceTrack, check_scores
from service.errors import InvalidParameterError

_FLOOR = np.log(1e-9)  # a frame's vote for an index it finds impossible, so one frame cannot veto


@dataclass(frozen=True)
class SeqSLAMConfig:
    """The service's former defaults were window 6 and speeds 0…2 (9 speeds); the published
    comparisons use a 10-frame window."""

    window: int = 10  # query frames combined (1 = no filtering)
    min_speed: float = 0.0  # reference frames advanced per query frame
    max_speed: float = 2.0
    speed_step: float = 0.25

    def speeds(self) -> np.ndarray:
        if self.window < 1 or self.speed_step <= 0 or self.max_speed < self.min_speed:
            raise InvalidParameterError(f"invalid SeqSLAM filter configuration {self}")
        n = int(np.floor((self.max_speed - self.min_speed) / self.speed_step + 1e-9)) + 1
        return self.min_speed + self.speed_step * np.arange(n)


class SeqSLAMFilter:
    """One vehicle's window filter over a route of ``n_frames`` frames."""

    def __init__(self, n_frames: int, config: SeqSLAMConfig | None = None) -> None:
        if int(n_frames) < 1:
            raise InvalidParameterError(f"a route has at least one frame, got {n_frames}")
        self.n_frames = int(n_frames)
        self.config = config or SeqSLAMConfig()
        self._velocities = self.config.speeds()
        self._history: deque[np.ndarray] = deque(maxlen=self.config.window)

    def reset(self) -> None:
        self._history.clear()

    @property
    def nbytes(self) -> int:
        """Memory the full window of this vehicle's history holds."""
        return 8 * self.n_frames * self.config.window

    def update(self, frame_log_scores: np.ndarray) -> SequenceEstimate:
        scores = check_scores(frame_log_scores, self.n_frames)
        posterior = scores - logsumexp(scores)
        self._history.appendleft(np.maximum(posterior, _FLOOR))  # newest first
        positions = np.arange(self.n_frames)
        best_total = np.full(self.n_frames, -np.inf)
        best_speed = np.zeros(self.n_frames)
        for v in self._velocities:
            total = np.zeros(self.n_frames)
            for s, past in enumerate(self._history):
                idx = np.rint(positions - v * s).astype(np.int64)
                inside = (idx >= 0) & (idx < self.n_frames)
                total += np.where(inside, past[np.clip(idx, 0, self.n_frames - 1)], _FLOOR)
            better = total > best_total
            best_total[better] = total[better]
            best_speed[better] = v
        best = int(np.argmax(best_total))
        log_conf = float(best_total[best] - logsumexp(best_total))
        return SequenceEstimate(
            best, float(np.exp(log_conf)), log_conf, len(self._history), float(best_speed[best])
        )


def seqslam_sequence(scores: np.ndarray, config: SeqSLAMConfig | None = None) -> SequenceTrack:
    """One fresh window filter over a drive's frame scores ``(T, N)``."""
    filt = SeqSLAMFilter(scores.shape[1], config)
    est = [filt.update(row) for row in scores]
    return SequenceTrack(
        np.array([e.index for e in est], dtype=np.int64),
        np.array([e.confidence for e in est]),
        np.array([e.speed for e in est]),
        scores.argmax(axis=1).astype(np.int64),
    )

"""The SeqSLAM-style window filter (kept by name: ``SequenceConfig(method="seqslam")``).

In the spirit of SeqSLAM, a vehicle visits reference frames in order at some speed ``v``
(reference frames per query frame). The filter keeps the last ``window`` queries' frame
log-posteriors and scores each current position ``i`` and grid speed ``v`` by
``Σ_s L_{t−s}(i − v·s)``: a position is believed when the recent frames agree along a
straight trajectory ending there. Each update re-scans the whole window at every speed, so it
costs ``O(window · S · N)`` per frame (the HMM filter in :mod:`service.encoding.sequence`
costs ``O(S · N)``).
"""

from __future__ import annotations

from collections import deque

import numpy as np
from scipy.special import logsumexp

from service.encoding.sequence import SequenceConfig, SequenceEstimate, check_scores
from service.errors import InvalidParameterError

_FLOOR = np.log(1e-9)  # a frame's vote for an index it finds impossible, so one frame cannot veto


class SeqSLAMFilter:
    """One vehicle's window filter over a route of ``n_frames`` frames."""

    def __init__(self, n_frames: int, config: SequenceConfig | None = None) -> None:
        if int(n_frames) < 1:
            raise InvalidParameterError(f"a route has at least one frame, got {n_frames}")
        self.n_frames = int(n_frames)
        self.config = config or SequenceConfig(method="seqslam")
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
        return SequenceEstimate(best, float(np.exp(log_conf)), log_conf, len(self._history),
                                float(best_speed[best]))  # fmt: skip

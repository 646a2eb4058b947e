"""Repeated views: what a query frame that looks like the previous one says about the vehicle.

A stopped vehicle's camera sends the same view again, up to sensor noise, and the model scores
it over the route almost exactly as it scored the previous frame. Taking every such frame as
new, independent evidence of *where* the vehicle is lets an alias that scores a little better
than the true frame win a long stop by repetition. The filter reads the repetition instead:

- **novelty** ``n = (1 − ρ) / (1 − ρ₁)``: ``ρ`` the correlation of this query's and the
  previous query's scores over the route's sample frames
  (:func:`~service.encoding.drive_scoring.route_sample`, the frames a tracker scores every
  query anyway), ``ρ₁`` the correlation of this query's scores at those frames with its scores
  at the frames that follow them: how much a query's scores change from one frame of the
  route to the next, so ``n`` is in units of a one-frame move whatever the model (a model
  whose scores are smooth along the route moves less in one frame). It measures the
  likelihood's own change, not the descriptor's, so a noisy copy of a view (a real camera)
  counts as a repeat as well as an equal row. ``Redundancy r = clip(1 − n / repeat_novelty,
  0, 1)`` (1: the same scores, 0: a view at least ``repeat_novelty`` one-frame moves away),
  and the weight of the frame's evidence in a stopped state ``w = 1 − r``: a repeat adds
  nothing to a stopped vehicle's belief about its place (its view was counted when it was
  new); a moving state takes the evidence whole.
- **speed evidence** (only with ``repeat_speed``): a vehicle at speed ``v`` sends a repeated view with probability
  ``p(v) = repeat_stopped · (1 − |v|) + repeat_moving · |v|`` for ``|v| < 1`` (a slow vehicle's
  consecutive views overlap) and ``repeat_moving`` from one frame per query frame on. A
  frame's novelty reads as a repeat (weight ``r``), a new view (weight ``u``: 0 up to
  ``move_novelty / 2``, 1 from ``move_novelty`` on; with ``move_novelty = 0`` every frame that
  is no repeat) or neither; a state's weight is ``r · p(v) + u · (1 − p(v)) + (1 − r − u)``.

A frame that comes with odometry is read as new: the measured displacement moves every state,
so the speed states say nothing about the motion and a stopped state is not held in place.

``repeat_novelty = 0`` turns both off: every frame is new evidence for every state. Measured
on Nordland (``docs/RESULTS.md``, "Drives"): the default (``repeat_novelty = 1e-3``, tempering
only) follows a stop's repeated or near-identical (3 % descriptor noise) frames better with
every method and leaves a stop whose frames differ more (30 % descriptor noise) as it was;
``repeat_speed`` follows the repeated stops better still, but a new view is then evidence
against stopping, and a stopped camera whose frames differ by 30 % noise is driven out of its
stop: off by default.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from service.encoding.sequence_config import SequenceConfig


@dataclass(frozen=True)
class Repeat:
    """One query frame's repetition of the previous one."""

    weight: float  # w: weight of its place evidence in a stopped state, in [0, 1]
    speed: np.ndarray | None  # float32 (S,) weight of each speed state; None: all equal


NEW = Repeat(1.0, None)  # a frame with nothing to compare to (or repeats off)


def repeat_probability(speeds: np.ndarray, config: SequenceConfig) -> np.ndarray:
    """``p(v)`` of every speed state (see module doc), float64."""
    a = np.clip(np.abs(np.asarray(speeds, dtype=np.float64)), 0.0, 1.0)
    return config.repeat_stopped * (1.0 - a) + config.repeat_moving * a


class RepeatDetector:
    """A vehicle's test of each query frame against the previous one (see module doc)."""

    def __init__(self, speeds: np.ndarray, config: SequenceConfig) -> None:
        self.config = config
        self._p = repeat_probability(speeds, config)
        self._previous: np.ndarray | None = None

    def reset(self) -> None:
        self._previous = None

    def measure(
        self, odometry: float | None, scores: Callable[[], tuple[np.ndarray, np.ndarray]]
    ) -> Repeat:
        """The repetition of a query frame, or :data:`NEW` without measuring it when the test
        is off or the frame comes with odometry (the measured displacement moves every state:
        the speed belief does not move it). ``scores()`` gives the query's scores over the
        route's sample frames and their successors (:meth:`observe`); it is called only when
        the test runs, since scoring the successors costs a tracker extra frames."""
        if self.config.repeat_novelty <= 0 or odometry is not None:
            return NEW
        return self.observe(*scores())

    def observe(self, sample_scores: np.ndarray, next_scores: np.ndarray) -> Repeat:
        """The repetition of a query whose scores over the route's sample frames are
        ``sample_scores`` and at the frames after them ``next_scores`` (:func:`successors`;
        finite or ``-inf``); it becomes the previous query."""
        scale = self.config.repeat_novelty
        if scale <= 0:
            return NEW
        z = standardised(sample_scores)
        previous, self._previous = self._previous, z
        z1 = standardised(next_scores)
        if previous is None or z is None or z1 is None or previous.shape != z.shape:
            return NEW
        step = 1.0 - float(z @ z1) / z.size  # a one-frame move's change of the scores
        novelty = (1.0 - float(z @ previous) / z.size) / max(step, 1e-9)
        r = min(1.0, max(0.0, 1.0 - novelty / scale))
        if not self.config.repeat_speed:
            return Repeat(1.0 - r, None) if r > 0.0 else NEW
        half = 0.5 * self.config.move_novelty
        u = min(1.0 - r, max(0.0, (novelty - half) / half)) if half > 0 else 1.0 - r
        p = self._p
        return Repeat(1.0 - r, (r * p + u * (1.0 - p) + (1.0 - r - u)).astype(np.float32))


def successors(sample: np.ndarray, n_frames: int) -> np.ndarray:
    """The frame after each of ``sample`` (the last frame's own for the route's last)."""
    return np.minimum(np.asarray(sample) + 1, n_frames - 1)


def standardised(scores: np.ndarray) -> np.ndarray | None:
    """``scores`` (frames the model did not score at its lowest score) with mean 0 and
    variance 1; ``None`` for a flat row (no spread: nothing to correlate)."""
    s = np.asarray(scores, dtype=np.float64)
    finite = np.isfinite(s)
    if not finite.any():
        return None
    if not finite.all():
        s = np.where(finite, s, s[finite].min())
    s = s - s.mean()
    std = float(np.sqrt(np.mean(s * s)))
    if not std > 1e-12 * max(1.0, float(np.abs(s).max())):
        return None
    return s / std

"""A vehicle's filter whose per-frame cost does not grow with the route once it is localised.

:class:`DriveTracker` runs the sequence filter's model (:mod:`service.encoding.sequence`) in
two modes:

- **whole**: the filter over every frame of the route, ``O(S·N)`` per query frame, until the
  belief is concentrated (``tracking_mass`` of it within ``track_radius`` of the estimate);
- **windows**: the belief on a few windows of ``2·track_radius + 1`` frames (the first around
  the estimate), the rest of the route as one *outside* mass spread uniformly. A window moves
  with the belief; mass that leaves it joins the outside. Every ``check_every`` frames a global
  check asks the model's scorer (:mod:`service.encoding.drive_scoring`) for the best-scoring
  places anywhere on the route and opens a window at each one outside the current windows, at
  the outside density: a kidnapped vehicle's true place then gathers evidence as the whole
  filter's would, and takes over once it is the most probable. Windows no better than the
  outside are closed after a probation.

When the windows explain the frames no better than the route does on average (a running
evidence ratio), or the outside holds more than half the mass (lost), the tracker **widens**:
its global checks open windows at up to ``window_frames // width`` candidate places, not
``candidates``, until the evidence is back. It goes back to the whole route only as far as
``whole_route_budget`` allows: a credit of that many state updates per frame, a whole-route
frame costing ``S·N`` and going there and back ``S·N`` each. On a short route (``S·N`` within
the budget) every such frame goes to the whole route, as the whole filter would; on a long one
a relocalisation is rare (once every ``~3·S·N / budget`` frames at most) and lasts while its
credit does, after which the tracker opens windows at the whole posterior's best places. A
vehicle not yet localised (a fresh tracker) runs on the whole route until its belief
concentrates, whatever the budget.

The emission is the whole filter's: z-scored against the spread of the query's scores over the
route (a fixed sample of frames for a code's scorer) and scaled by ``emission_scale``. Per
frame in windows mode: ``O(S·B·W)`` for ``B ≤ 16`` windows of ``W`` frames, the scorer's window
and sample frames, and a global check amortised over ``check_every`` frames.
"""

from __future__ import annotations

from collections import deque
from typing import Any

import numpy as np

from service.encoding.motion import MotionModel
from service.encoding.repeats import Repeat, RepeatDetector
from service.encoding.sequence import (
    _MIN_LOG_LIKELIHOOD,
    SequenceEstimate,
    SequenceFilter,
    apply_evidence,
    estimate_at,
    mean_evidence,
)
from service.encoding.sequence_config import SequenceConfig
from service.encoding.tracking_windows import (
    best_places,
    covered,
    frames_outside,
    recentre,
    windows_to_keep,
)
from service.errors import InvalidInputError

MAX_WINDOWS = 16  # windows while the evidence holds (window_frames // width once widened)
PROBATION = 8  # frames a candidate window stays open, at least
WIDE_PROBATION = 32  # … and while widened
REPLAY = 8  # a new window is opened with the evidence of this many earlier frames
LOST = 0.5  # outside mass beyond which the tracker goes back to the whole route
CHECK_CLASSES = 2048  # class scores per frame a code's global checks may cost, amortised
EVIDENCE_MEMORY = 0.2  # weight of the newest frame in the running evidence ratio
EVIDENCE_LOST = 0.0  # a running log evidence ratio at or below this: the windows lost the vehicle
BANKED = REPLAY  # whole-route frames the relocalisation credit may save up
_FLAT = 1e-10


class DriveTracker:
    """One vehicle's filter on a route scored by ``scorer`` (see the module doc)."""

    def __init__(self, scorer: Any, config: SequenceConfig | None = None) -> None:
        self.scorer = scorer
        self.config = config or SequenceConfig()
        self.n_frames = int(scorer.n_frames)
        self.motion = MotionModel(self.config)
        self.speeds = self.motion.speeds
        self.width = 2 * self.config.track_radius + 1
        self.windowed_allowed = self.config.tracking and self.n_frames >= 4 * self.width
        # a code's global check scores all Στ classes: spread it so its amortised cost is
        # bounded (a lost vehicle is caught by the evidence test every frame meanwhile)
        cost = int(getattr(scorer, "check_cost", 0))
        self.check_interval = max(self.config.check_every, -(-cost // CHECK_CLASSES))
        self.whole_cost = int(self.speeds.size) * self.n_frames  # state updates a whole frame
        # windows never hold more than the whole route's state (plus a check's candidates)
        self.max_windows = max(1, min(self.config.window_frames, self.n_frames) // self.width)
        self.repeats = RepeatDetector(self.speeds, self.config)
        self.reset()

    # -- state -----------------------------------------------------------------------
    def reset(self) -> None:
        """Forget the vehicle."""
        self.whole: SequenceFilter | None = SequenceFilter(self.n_frames, self.config)
        self.P: np.ndarray | None = None  # (S, B, W) window states
        self.lo = np.zeros(0, dtype=np.int64)  # each window's first frame
        self.age = np.zeros(0, dtype=np.int64)
        self.outside = 0.0  # posterior mass outside the windows
        self.evidence = 0.0  # running log ratio: the windows' evidence over the route's
        self.frames = 0
        self.recent: deque[tuple[Any, float | None, Repeat]] = deque(maxlen=REPLAY)
        self.repeats.reset()
        self.localised = False  # tracked once: from then on the whole route costs credit
        self.credit = 0.0  # state updates the tracker may spend on the whole route
        self.wide = False  # weak evidence: global checks open up to max_windows windows
        self.relocalisations = 0

    def start_at(self, frame: int) -> None:
        """Start tracking a vehicle known to stand at ``frame`` (a position fix, or where its
        last drive ended): one window around it, every speed equally likely, the rest of the
        route at the relocalisation level. Without tracking (or on a short route) the whole
        filter starts from the same belief."""
        frame = int(frame)
        if not 0 <= frame < self.n_frames:
            raise InvalidInputError(f"frame {frame} is not on the route (0 … {self.n_frames - 1})")
        self.reset()
        S = self.speeds.size
        eps = self.config.relocalization
        if not self.windowed_allowed:
            assert self.whole is not None
            state = np.full((S, self.n_frames), eps / (S * self.n_frames), dtype=np.float32)
            state[:, frame] += np.float32((1.0 - eps) / S)
            self.whole.set_state(state, 0)
            return
        lo = int(np.clip(frame - self.config.track_radius, 0, self.n_frames - self.width))
        P = np.full((S, 1, self.width), eps / (S * self.n_frames), dtype=np.float32)
        P[:, 0, frame - lo] += np.float32((1.0 - eps) / S)
        self.whole, self.P = None, P
        self.lo = np.array([lo], dtype=np.int64)
        self.age = np.array([PROBATION], dtype=np.int64)
        self.outside = eps * (self.n_frames - self.width) / self.n_frames
        self.evidence = 1.0
        self.localised = True

    @property
    def mode(self) -> str:
        return "whole" if self.whole is not None else "windows"

    @property
    def nbytes(self) -> int:
        """Memory this vehicle's state holds now."""
        if self.whole is not None:
            return self.whole.nbytes
        assert self.P is not None
        return int(self.P.nbytes + self.lo.nbytes + self.age.nbytes)

    @property
    def max_nbytes(self) -> int:
        """The most this vehicle's state can hold (the whole route's posterior)."""
        return int(self.speeds.size * self.n_frames * 4)

    @property
    def posterior(self) -> np.ndarray:
        """Posterior over frames ``(N,)`` float64 (outside mass spread uniformly)."""
        if self.whole is not None:
            return self.whole.posterior
        out = np.full(self.n_frames, self.outside / max(1, self._n_outside()))
        out[self._covered()] = 0.0
        assert self.P is not None
        marg = self.P.sum(axis=0, dtype=np.float64)
        for b, lo in enumerate(self.lo.tolist()):
            out[lo : lo + self.width] += marg[b]
        return out / out.sum()

    def _covered(self) -> np.ndarray:
        return covered(self.lo, self.width, self.n_frames)

    def _n_outside(self) -> int:
        return frames_outside(self.lo, self.width, self.n_frames)

    # -- update ----------------------------------------------------------------------
    def update(self, prep: Any, odometry: float | None = None) -> SequenceEstimate:
        """Fold in one prepared query (``scorer.prepare_many``) and the displacement since the
        last frame when measured; return the estimate."""
        self.frames += 1
        recent = list(self.recent)
        repeat = self.repeats.measure(odometry, lambda: (
            np.asarray(self.scorer.sample_scores(prep)),
            np.asarray(self.scorer.next_scores(prep))))  # fmt: skip
        self.recent.append((prep, odometry, repeat))
        budget = float(self.config.whole_route_budget)
        self.credit = min(self.credit + budget, max(budget, BANKED * self.whole_cost))
        if self.whole is not None and self.localised:
            if self.credit < self.whole_cost and self.windowed_allowed:
                self._leave_whole()  # out of credit: back to windows at its best places
                return self._update_windows(prep, odometry, repeat, recent)
            self.credit -= self.whole_cost
        if self.whole is not None:
            row = self.scorer.full(prep)
            est = self.whole.update(row, odometry, repeat)
            if self.windowed_allowed and self.frames >= 2:
                self._maybe_track(est)
            return est
        return self._update_windows(prep, odometry, repeat, recent)

    def _maybe_track(self, est: SequenceEstimate) -> None:
        assert self.whole is not None
        r = self.config.track_radius
        lo = int(np.clip(est.index - r, 0, self.n_frames - self.width))
        post = self.whole.posterior
        inside = float(post[lo : lo + self.width].sum())
        if inside < self.config.tracking_mass:
            return
        self._enter_windows(np.array([lo], dtype=np.int64), wide=False)

    def _leave_whole(self) -> None:
        """From the whole route to windows at the posterior's best places (up to
        ``max_windows``, the best first), the rest of its mass the outside; widened."""
        assert self.whole is not None
        self._enter_windows(best_places(self.whole.posterior, self.width, self.max_windows),
                            wide=True)  # fmt: skip

    def _enter_windows(self, lo_arr: np.ndarray, wide: bool) -> None:
        """From the whole route to windows starting at ``lo_arr`` (the first one past its
        probation), holding the whole state's mass there; the rest is the outside's."""
        assert self.whole is not None
        state = self.whole.state  # (S, N), sums to 1
        idx = lo_arr[:, None] + np.arange(self.width)[None, :]
        self.P = np.ascontiguousarray(state[:, idx], dtype=np.float32)  # (S, B, W)
        for b in range(1, lo_arr.size):  # a frame in two windows counts once
            dup = np.isin(idx[b], idx[:b].ravel())
            self.P[:, b, dup] = 0.0
        self.lo = lo_arr
        self.age = np.zeros(lo_arr.size, dtype=np.int64)
        self.age[0] = PROBATION
        self.outside = max(0.0, 1.0 - float(self.P.sum(dtype=np.float64)))
        self.evidence = 1.0
        self.whole = None
        self.localised, self.wide = True, wide

    def _emission(self, prep: Any, idx: np.ndarray) -> tuple[np.ndarray, float]:
        """Likelihood of the window frames ``idx`` and the mean likelihood outside."""
        cfg = self.config
        s = np.asarray(self.scorer.frames(prep, idx), dtype=np.float64)
        ref = np.asarray(self.scorer.sample_scores(prep), dtype=np.float64)
        finite = ref[np.isfinite(ref)]
        lowest = finite.min() if finite.size else 0.0
        ref = np.where(np.isfinite(ref), ref, lowest)
        s = np.where(np.isfinite(s), s, lowest)
        hi = max(float(s.max()), float(ref.max()))
        scale = cfg.emission_scale
        if cfg.emission == "zscore":
            std = float(ref.std())
            if not std > _FLAT * max(abs(hi), abs(float(ref.mean()))):
                return np.ones(idx.size, dtype=np.float32), 1.0
            scale /= std
        e = np.maximum((s - hi) * scale, _MIN_LOG_LIKELIHOOD)
        e_out = np.maximum((ref - hi) * scale, _MIN_LOG_LIKELIHOOD)
        return np.exp(e).astype(np.float32), float(np.exp(e_out).mean())

    def _update_windows(
        self, prep: Any, odometry: float | None, repeat: Repeat,
        recent: list[tuple[Any, float | None, Repeat]],
    ) -> SequenceEstimate:  # fmt: skip
        cfg = self.config
        assert self.P is not None
        S, B, W = self.P.shape
        N = self.n_frames
        eps = cfg.relocalization
        n_out = max(1, self._n_outside())
        # predict: windows move with the motion model; what leaves them joins the outside
        before = self.P.sum(axis=(0, 2), dtype=np.float64)
        pred = np.empty_like(self.P)
        self.motion.predict(self.P, pred, np.empty_like(self.P), 1.0 - eps, odometry)
        left = np.maximum(0.0, (1.0 - eps) * before - pred.sum(axis=(0, 2), dtype=np.float64))
        # a window at an end of the route (its peak is there) loses mass off the route: gone
        interior = (self.lo > 0) & (self.lo + W < N)
        self.outside = self.outside * (1.0 - eps) + float(left[interior].sum())
        pred += np.float32(eps / (S * N))  # the uniform jump, on the windows …
        self.outside += eps * n_out / N  # … and outside them
        if self.frames % self.check_interval == 0:
            pred = self._open_candidates(prep, pred, n_out, recent)
        B = pred.shape[1]
        idx = (self.lo[:, None] + np.arange(W)[None, :]).ravel()
        lik, lik_out = self._emission(prep, idx)
        out_factor = mean_evidence(lik_out, repeat, self.speeds.size, self.motion.stops)
        inside = float(pred.sum(dtype=np.float64))
        apply_evidence(pred, lik.reshape(B, W), repeat, self.motion.stops, out=pred)
        # how much better the windows explain this frame than the route does on average
        ratio = float(pred.sum(dtype=np.float64)) / max(inside * out_factor, 1e-300)
        self.evidence += EVIDENCE_MEMORY * (np.log(max(ratio, 1e-300)) - self.evidence)
        self.outside *= out_factor
        total = float(pred.sum(dtype=np.float64)) + self.outside
        if not (total > 1e-300 and np.isfinite(total)):  # underflow: start over on this frame
            self._to_whole(uniform=True)
            assert self.whole is not None
            return self.whole.update(self.scorer.full(prep), None, repeat)
        pred *= np.float32(1.0 / total)
        self.outside /= total
        self.P = pred
        self.age += 1
        self._recentre()
        self._close_windows()
        est = self._estimate()
        lost = self.age.max() >= PROBATION and self.evidence <= EVIDENCE_LOST
        weak = self.outside > LOST or lost
        self.wide = weak or (self.wide and self.evidence < 1.0)
        if weak and self.credit >= 2 * self.whole_cost:
            self.credit -= self.whole_cost  # going there costs as much as a frame on it
            self.relocalisations += 1
            self._to_whole()
        return est

    def _open_candidates(
        self, prep: Any, pred: np.ndarray, n_out: int,
        recent: list[tuple[Any, float | None, Repeat]],
    ) -> np.ndarray:  # fmt: skip
        """``pred`` with a window at each candidate place that lies outside every window: the
        outside density, carried through the evidence of the last :data:`REPLAY` frames
        relative to the outside's (as the whole filter would have)."""
        m = self.config.candidates
        if self.wide:
            m = max(m, self.max_windows - self.lo.size)
        cands = np.asarray(self.scorer.candidates(prep, m))
        S, W = pred.shape[0], pred.shape[2]
        density = self.outside / (S * n_out)
        r = self.config.track_radius
        new_lo: list[int] = []
        for c in cands.tolist():
            if any(lo <= c < lo + W for lo in [*self.lo.tolist(), *new_lo]):
                continue
            new_lo.append(int(np.clip(c - r, 0, self.n_frames - W)))
        if not new_lo:
            return pred
        add = np.full((S, len(new_lo), W), density, dtype=np.float32)
        self.outside = max(0.0, self.outside - density * S * W * len(new_lo))
        lo_arr = np.array(new_lo, dtype=np.int64)
        idx = (lo_arr[:, None] + np.arange(W)[None, :]).ravel()
        for old, odo, rep in recent:
            moved = np.empty_like(add)
            self.motion.predict(add, moved, np.empty_like(add), 1.0, odo)
            moved += np.float32(density * self.config.relocalization)
            lik, lik_out = self._emission(old, idx)
            apply_evidence(moved, lik.reshape(len(new_lo), W), rep, self.motion.stops, out=moved)
            mean = mean_evidence(lik_out, rep, self.speeds.size, self.motion.stops)
            moved *= np.float32(1.0 / max(mean, 1e-30))
            add = moved
        np.minimum(add, np.float32(1.0), out=add)
        self.lo = np.concatenate([self.lo, np.array(new_lo, dtype=np.int64)])
        self.age = np.concatenate([self.age, np.zeros(len(new_lo), dtype=np.int64)])
        return np.concatenate([pred, add], axis=1)

    def _recentre(self) -> None:
        """Move each window whose peak drifted more than a quarter width from its centre."""
        assert self.P is not None
        self.outside = recentre(self.P, self.lo, self.outside, self.config.track_radius,
                                self.n_frames)  # fmt: skip

    def _close_windows(self) -> None:
        """Close windows past probation that are no better than the outside (and the weakest
        beyond :data:`MAX_WINDOWS`); their mass joins the outside."""
        assert self.P is not None
        if self.P.shape[1] == 1:
            return
        mass = self.P.sum(axis=(0, 2), dtype=np.float64)
        level = 2.0 * self.outside * self.width / max(1, self._n_outside())  # were it outside
        most = self.max_windows if self.wide else min(MAX_WINDOWS, self.max_windows)
        keep = windows_to_keep(mass, self.age, level,
                               WIDE_PROBATION if self.wide else PROBATION, most)  # fmt: skip
        if keep.all():
            return
        self.outside += float(mass[~keep].sum())
        self.P = np.ascontiguousarray(self.P[:, keep])
        self.lo, self.age = self.lo[keep], self.age[keep]

    def _estimate(self) -> SequenceEstimate:
        assert self.P is not None
        marg = self.P.sum(axis=0)  # (B, W)
        b, i = np.unravel_index(int(np.argmax(marg)), marg.shape)
        mass = float(marg.sum(dtype=np.float64)) + self.outside
        return estimate_at(self.P[:, b, i], marg[b], int(i), mass, self.speeds,
                           self.config.confidence_radius, self.frames, int(self.lo[b]))  # fmt: skip

    def _to_whole(self, uniform: bool = False) -> None:
        """Back to the whole route: the outside spread uniformly, the windows pasted in."""
        whole = SequenceFilter(self.n_frames, self.config)
        if not uniform:
            assert self.P is not None
            S = self.speeds.size
            state = np.full((S, self.n_frames), self.outside / (S * max(1, self._n_outside())),
                            dtype=np.float32)  # fmt: skip
            state[:, self._covered()] = 0.0
            for b, lo in enumerate(self.lo.tolist()):
                state[:, lo : lo + self.width] += self.P[:, b]
            whole.set_state(state, self.frames)
        self.whole, self.P = whole, None
        self.lo = np.zeros(0, dtype=np.int64)
        self.age = np.zeros(0, dtype=np.int64)
        self.outside = 0.0


def track_scores(scores: np.ndarray, config: SequenceConfig | None = None) -> list[SequenceEstimate]:
    """A fresh tracker over a drive's frame scores ``(T, N)`` (tests, benches)."""
    from service.encoding.drive_scoring import MatrixScorer

    tracker = DriveTracker(MatrixScorer(np.asarray(scores)), config)
    return [tracker.update(t) for t in range(len(scores))]

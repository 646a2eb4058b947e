"""Sequence localisation: a recursive Bayes filter over the route (beyond the paper).

A vehicle drives the route at an unknown, changing speed; it may stop, reverse, or be moved.
The filter is the forward pass of a hidden Markov model whose state is ``(speed, frame)``:

- **motion** (:mod:`service.encoding.motion`): the speed prior (a random walk on a speed grid,
  stops, reversing) or, for a frame that comes with one, the vehicle's own odometry.
- **relocalisation**: with probability ``relocalization`` the vehicle may be anywhere (a uniform
  jump), so the filter recovers when it has lost track or the vehicle was moved.
- **emission**: one query's frame log-scores ``L`` (``(N,)``, from a model's
  ``frame_log_scores``). With ``emission="zscore"`` (default) they are standardised per query,
  ``(L − mean L) / std L`` over the frames the model scored, and multiplied by
  ``emission_scale``: the filter then needs no per-model calibration (it is invariant to any
  positive affine change of the scores). ``emission="raw"`` uses ``emission_scale · L``, for
  calibrated log-likelihoods. A frame the model did not score (``−inf``, e.g. outside a
  chunked model's top chunks) gets the lowest score the model gave, so one query cannot veto.
- **repeated views** (:mod:`service.encoding.repeats`): a frame whose scores over the route
  are nearly the previous frame's (a stopped vehicle's camera) adds little to a stopped state's
  belief about its place (and, with ``repeat_speed``, is evidence of a low speed).

One update costs ``O(S·N)`` for ``S`` states (:attr:`SequenceConfig.n_states`; a few array
passes, nothing depends on how many frames came before). A vehicle holds its ``(S, N)``
float32 posterior; an update allocates two more arrays of that size for its duration and
keeps nothing. The posterior lives in linear space rescaled to sum 1 each frame; should it
ever underflow (a motion prior that drives every state off the route, a vanishing jump
probability) the filter restarts from the frame's own evidence. :mod:`service.encoding.tracking`
runs the same model on windows around the belief once a vehicle is localised, at a cost that
does not grow with the route.

The estimate is the frame with the largest posterior (speeds marginalised); its confidence is
the posterior mass within ``confidence_radius`` frames of it.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Any

import numpy as np

from service.encoding.motion import MotionModel
from service.encoding.repeats import NEW, Repeat, RepeatDetector, successors
from service.encoding.sequence_config import MAX_SPEEDS, SequenceConfig
from service.errors import InvalidInputError, InvalidParameterError

__all__ = [
    "MAX_SPEEDS", "SequenceConfig", "SequenceEstimate", "SequenceFilter", "SequenceTrack",
    "check_odometry", "check_scores", "emission_log_likelihood", "filter_sequence",
    "sequence_localize",
]  # fmt: skip

_BLOCK = 256  # query rows scored per model call in :func:`sequence_localize`, at most
_SCORE_BUDGET = 1 << 22  # … and at most this many frame scores (32 MiB of float64) per call
_FLAT = 1e-10  # a row whose spread is below this fraction of its magnitude is flat
_MIN_LOG_LIKELIHOOD = -60.0  # one frame shrinks a state by at most e⁻⁶⁰ (float32 stays normal)
MAX_DISPLACEMENT = 1e6  # |odometry| per frame, reference frames


@dataclass(frozen=True)
class SequenceEstimate:
    index: int  # most probable frame
    confidence: float  # posterior mass within ``confidence_radius`` frames of ``index``
    log_score: float  # log of ``confidence``
    frames_used: int  # query frames combined since the last reset
    speed: float  # posterior mean speed at ``index``, frames per query frame


def check_scores(scores: Any, n_frames: int) -> np.ndarray:
    """One query's frame scores as float64 ``(N,)``: no NaN or +inf, at least one finite."""
    L = np.asarray(scores, dtype=np.float64)
    if L.shape != (n_frames,):
        raise InvalidInputError(f"expected {n_frames} frame scores, got shape {L.shape}")
    if not np.isfinite(L).all():  # one pass in the common case; the causes only when needed
        if np.isnan(L).any() or np.isposinf(L).any():
            raise InvalidInputError("frame scores contain NaN or +inf")
        if not np.isfinite(L).any():
            raise InvalidInputError("every frame score is -inf: the model scored no frame")
    return L


def emission_log_likelihood(L: np.ndarray, config: SequenceConfig) -> np.ndarray:
    """Scaled log-likelihood of every frame, ``≤ 0`` with maximum ``0`` (see module doc);
    ``L`` as :func:`check_scores` returns it."""
    lo, hi = L.min(), L.max()
    if np.isneginf(lo):  # frames the model did not score get its lowest score
        finite = np.isfinite(L)
        L = np.where(finite, L, L[finite].min())
    scale = config.emission_scale
    if config.emission == "zscore":
        mean = L.mean()
        centred = L - mean
        std = float(np.sqrt(np.square(centred, out=centred).mean()))  # no BLAS call: no threads
        if not std > _FLAT * max(abs(float(hi)), abs(float(mean))):
            return np.zeros_like(L)  # a flat row (up to float rounding) carries no evidence
        scale /= std
    e = L - hi
    e *= scale
    np.maximum(e, _MIN_LOG_LIKELIHOOD, out=e)  # no float32 denormals downstream
    return e


class SequenceFilter:
    """One vehicle's recursive Bayes filter over a route of ``n_frames`` frames."""

    def __init__(self, n_frames: int, config: SequenceConfig | None = None) -> None:
        if int(n_frames) < 1:
            raise InvalidParameterError(f"a route has at least one frame, got {n_frames}")
        self.n_frames = int(n_frames)
        self.config = config or SequenceConfig()
        self.motion = MotionModel(self.config)
        self.speeds = self.motion.speeds
        self._post = np.empty((self.speeds.size, self.n_frames), dtype=np.float32)
        self._repeats = RepeatDetector(self.speeds, self.config)
        self.reset()

    def reset(self) -> None:
        """Forget the vehicle: every ``(speed, frame)`` equally likely."""
        self._post.fill(1.0 / self._post.size)
        self._mass = 1.0  # the stored posterior sums to this (normalised lazily)
        self._frames = 0
        self._repeats.reset()

    @property
    def nbytes(self) -> int:
        """Memory this vehicle's state holds (an update needs twice that again, briefly)."""
        return int(self._post.nbytes)

    @property
    def frames_used(self) -> int:
        return self._frames

    @property
    def posterior(self) -> np.ndarray:
        """Posterior over frames (speeds marginalised), ``(N,)`` float64 summing to 1."""
        marginal = self._post.sum(axis=0, dtype=np.float64)
        return marginal / marginal.sum()

    @property
    def state(self) -> np.ndarray:
        """Joint posterior over ``(speed, frame)``, ``(S, N)`` float64 summing to 1."""
        joint = self._post.astype(np.float64)
        return joint / joint.sum()

    def set_state(self, state: np.ndarray, frames_used: int) -> None:
        """Start from a joint posterior ``(S, N)`` (e.g. a tracker's belief, made whole)."""
        if state.shape != self._post.shape:
            raise InvalidParameterError(f"expected a state of shape {self._post.shape}")
        self._post[...] = state
        self._mass = float(self._post.sum(dtype=np.float64))
        self._frames = int(frames_used)

    def update(
        self, frame_log_scores: np.ndarray, odometry: float | None = None,
        repeat: Repeat | None = None,
    ) -> SequenceEstimate:  # fmt: skip
        """Fold in one query's frame log-scores ``(N,)`` (and the displacement since the last
        frame, reference frames, when the vehicle measured it) and return the estimate;
        ``repeat``: the frame's repetition of the previous one when the caller measured it
        (:mod:`service.encoding.repeats`), else the filter measures it."""
        L = check_scores(frame_log_scores, self.n_frames)
        if repeat is None:
            repeat = self._repeats.measure(odometry, lambda: self._sample_scores(L))
        return self.update_likelihood(likelihood(L, self.config), odometry, repeat)

    def _sample_scores(self, L: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        from service.encoding.drive_scoring import route_sample

        sample = route_sample(self.n_frames)
        return L[sample], L[successors(sample, self.n_frames)]

    def update_likelihood(
        self, lik: np.ndarray, odometry: float | None = None, repeat: Repeat = NEW
    ) -> SequenceEstimate:
        """:meth:`update` with the frame's likelihood ``(N,)`` float32 already computed."""
        if odometry is not None:
            repeat = NEW
        if self._frames:
            eps = self.config.relocalization
            pred = np.empty_like(self._post)
            scratch = np.empty_like(self._post)
            self.motion.predict(self._post, pred, scratch, (1.0 - eps) / self._mass, odometry)
            pred += np.float32(eps / pred.size)  # the uniform jump
            apply_evidence(pred, lik, repeat, self.motion.stops, out=self._post)
        else:
            self._post *= lik[None, :]
        self._frames += 1
        est = self._estimate()
        if est is None:  # underflow: nothing of the prior survived this frame's evidence
            self._post.fill(1.0 / self._post.size)
            self._post *= lik[None, :]
            est = self._estimate()
            assert est is not None  # the likelihood is ≥ e⁻⁶⁰ everywhere
        return est

    def _estimate(self) -> SequenceEstimate | None:
        marginal = self._post.sum(axis=0)
        self._mass = float(marginal.sum(dtype=np.float64))
        if not (self._mass > 1e-30 and np.isfinite(self._mass)):
            return None
        best = int(np.argmax(marginal))
        return estimate_at(self._post[:, best], marginal, best, self._mass, self.speeds,
                           self.config.confidence_radius, self._frames)  # fmt: skip


def estimate_at(
    at_best: np.ndarray, marginal: np.ndarray, best: int, mass: float, speeds: np.ndarray,
    radius: int, frames: int, offset: int = 0,
) -> SequenceEstimate:  # fmt: skip
    """The estimate at ``best`` (an index into ``marginal``; the frame is ``best + offset``)."""
    near = float(marginal[max(0, best - radius) : best + radius + 1].sum(dtype=np.float64))
    conf = min(1.0, near / mass)
    col = at_best.astype(np.float64)
    total = col.sum()
    speed = float(speeds @ col / total) if total > 0 else 0.0  # mean speed at the estimate
    return SequenceEstimate(best + offset, conf, float(np.log(max(conf, 1e-300))), frames, speed)


def apply_evidence(
    pred: np.ndarray, lik: np.ndarray, repeat: Repeat, stops: list[int], out: np.ndarray
) -> None:
    """``out = pred ·`` one frame's evidence: the likelihood ``lik`` (broadcast over the
    frame axis, the last) for moving states, ``lik ** repeat.weight`` for the stopped rows
    ``stops``, times each state's speed weight (:mod:`service.encoding.repeats`); ``out`` may
    be ``pred``."""
    stopped = []
    if stops and repeat.weight < 1.0:
        tempered = np.power(lik, np.float32(repeat.weight))
        stopped = [(row, pred[row] * tempered) for row in stops]
    np.multiply(pred, lik, out=out)
    for row, values in stopped:
        out[row] = values
    if repeat.speed is not None:
        out *= repeat.speed.reshape((-1,) + (1,) * (out.ndim - 1))


def mean_evidence(lik: float, repeat: Repeat, n_states: int, stops: list[int]) -> float:
    """The mean over ``n_states`` states of what :func:`apply_evidence` gives a frame of
    likelihood ``lik``: the evidence of a mass spread evenly over the states."""
    per_state = np.full(n_states, lik)
    if stops:
        per_state[stops] = lik**repeat.weight
    if repeat.speed is not None:
        per_state *= repeat.speed
    return float(per_state.mean())


def likelihood(L: np.ndarray, config: SequenceConfig) -> np.ndarray:
    """One frame's likelihood of every frame, float32 in ``[e⁻⁶⁰, 1]``."""
    e = emission_log_likelihood(L, config)
    return np.exp(e, out=e).astype(np.float32)


def check_odometry(odometry: Any, n: int) -> np.ndarray:
    """Per-frame displacements as float64 ``(n,)``, NaN where a frame has none (``None`` in a
    list, NaN in a float array). Refused: another length, NaN (in a list) or infinity given as
    a value, ``|u| > 10⁶`` frames."""
    if isinstance(odometry, np.ndarray) and odometry.dtype != object:
        u = np.asarray(odometry, dtype=np.float64)  # an array marks frames without by NaN
        return _check_values(u, n, np.isnan(u))
    try:
        rows = list(odometry)
    except TypeError:
        raise InvalidInputError("odometry must be a list of displacements, one per frame") from None
    missing = np.array([r is None for r in rows], dtype=bool)
    try:
        u = np.array([np.nan if r is None else float(r) for r in rows], dtype=np.float64)
    except (TypeError, ValueError):
        raise InvalidInputError("odometry must hold numbers (or null for a frame without)") from None
    return _check_values(u, n, missing)


def odometry_in_frames(odometry_m: Any, n: int, spacing_m: Any) -> np.ndarray:
    """Displacements in metres (as :func:`check_odometry` takes them) in reference frames of a
    route whose frames lie ``spacing_m`` metres apart (finite and > 0, else refused)."""
    try:
        spacing = float(spacing_m)
    except (TypeError, ValueError):
        raise InvalidInputError(f"frame spacing must be a number of metres, got {spacing_m!r}") from None
    if not (np.isfinite(spacing) and spacing > 0):
        raise InvalidInputError(f"frame spacing must be a positive number of metres, got {spacing}")
    return check_odometry(check_odometry(odometry_m, n) / spacing, n)


def _check_values(u: np.ndarray, n: int, missing: np.ndarray) -> np.ndarray:
    if u.ndim != 1 or u.shape[0] != n:
        raise InvalidInputError(f"expected {n} odometry values, one per frame, got shape {u.shape}")
    given = u[~missing]
    if not np.isfinite(given).all():
        raise InvalidInputError("odometry contains NaN or infinity (send null for a frame without)")
    if given.size and np.abs(given).max() > MAX_DISPLACEMENT:
        raise InvalidInputError(
            f"an odometry displacement exceeds {MAX_DISPLACEMENT:.0f} frames per query frame"
        )
    return u


@dataclass(frozen=True)
class SequenceTrack:
    """Per-frame answers of one drive (all arrays have one entry per query frame)."""

    index: np.ndarray  # int64 filtered estimate
    confidence: np.ndarray  # float64
    speed: np.ndarray  # float64 posterior mean speed
    raw_index: np.ndarray  # int64 each frame's own best frame (argmax of its scores)

    def __len__(self) -> int:
        return int(self.index.shape[0])


def filter_sequence(
    scores: np.ndarray, config: SequenceConfig | None = None, odometry: Any = None
) -> SequenceTrack:
    """Run one fresh filter over a drive's frame scores ``(T, N)`` (rows in driving order),
    with per-frame ``odometry`` (``(T,)`` displacements in reference frames, ``None``/NaN-free;
    see :func:`check_odometry`) when the vehicle measured it. With ``config.tracking`` (the
    default) the filter tracks windows around its belief once localised
    (:class:`~service.encoding.tracking.DriveTracker`)."""
    S = np.asarray(scores)
    if S.ndim != 2 or S.shape[0] == 0:
        raise InvalidInputError(f"expected frame scores of shape (T, N) with T >= 1, got {S.shape}")
    config = config or SequenceConfig()
    u = None if odometry is None else check_odometry(odometry, S.shape[0])
    from service.encoding.drive_scoring import MatrixScorer
    from service.encoding.tracking import DriveTracker

    if config.tracking:
        tracker = DriveTracker(MatrixScorer(S), config)
        return _run(tracker.update, range(S.shape[0]), S.shape[0], u,
                    lambda t, _: int(np.argmax(S[t])))  # fmt: skip
    filt = SequenceFilter(S.shape[1], config)
    return _run(filt.update, (S[t] for t in range(S.shape[0])), S.shape[0], u,
                lambda _, row: int(np.argmax(row)))  # fmt: skip


def sequence_localize(
    model: Any, queries: Any, config: SequenceConfig | None = None, block: int | None = None,
    odometry: Any = None,
) -> SequenceTrack:  # fmt: skip
    """Localize ``queries`` (rows in driving order) as one drive on a fitted model that has
    ``frame_log_scores`` (every model of :mod:`service.encoding`), with optional per-frame
    ``odometry`` as in :func:`filter_sequence`. With ``config.tracking`` the model's drive
    scorer (:func:`~service.encoding.drive_scoring.drive_scorer`) scores only the frames the
    tracker needs; otherwise every frame's scores are computed ``block`` rows at a time
    (default: as many as fit ``_SCORE_BUDGET`` values, at most 256), so memory stays bounded
    for any drive and route length."""
    if not hasattr(model, "frame_log_scores"):
        raise InvalidParameterError(f"{type(model).__name__} gives no frame scores")
    Q = np.asarray(queries)
    if Q.ndim != 2 or Q.shape[0] == 0:
        raise InvalidInputError(
            f"expected query descriptors of shape (T, d) with T >= 1, got {Q.shape}"
        )
    config = config or SequenceConfig()
    u = None if odometry is None else check_odometry(odometry, Q.shape[0])
    n_frames = int(model.n_frames_)
    rows_per_call = block or max(1, min(_BLOCK, _SCORE_BUDGET // n_frames))
    if config.tracking:
        from service.encoding.drive_scoring import drive_scorer
        from service.encoding.tracking import DriveTracker

        scorer = drive_scorer(model)
        tracker = DriveTracker(scorer, config)
        preps = (p for s in range(0, Q.shape[0], rows_per_call)
                 for p in scorer.prepare_many(Q[s : s + rows_per_call]))  # fmt: skip
        raw = np.asarray(model.localize(Q).index)  # each frame's own answer, in one batch
        return _run(tracker.update, preps, Q.shape[0], u, lambda t, _: int(raw[t]))
    filt = SequenceFilter(n_frames, config)

    def rows() -> Iterable[np.ndarray]:
        for s in range(0, Q.shape[0], rows_per_call):
            yield from model.frame_log_scores(Q[s : s + rows_per_call])

    return _run(filt.update, rows(), Q.shape[0], u, lambda _, row: int(np.argmax(row)))


def _run(
    update: Callable[..., SequenceEstimate], rows: Iterable[Any], n: int, odometry: np.ndarray | None,
    raw_best: Callable[[int, Any], int],
) -> SequenceTrack:  # fmt: skip
    index = np.empty(n, dtype=np.int64)
    raw = np.empty(n, dtype=np.int64)
    conf = np.empty(n)
    speed = np.empty(n)
    for t, row in enumerate(rows):
        u = None if odometry is None or np.isnan(odometry[t]) else float(odometry[t])
        est = update(row, u)
        index[t], conf[t], speed[t] = est.index, est.confidence, est.speed
        raw[t] = raw_best(t, row)
    return SequenceTrack(index, conf, speed, raw)

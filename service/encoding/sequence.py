"""Sequence localisation: a recursive Bayes filter over the route (beyond the paper).

A vehicle drives the route in order at an unknown, slowly changing speed. The filter is the
forward pass of a hidden Markov model whose state is ``(speed, frame)``:

- **speeds**: a grid ``min_speed, min_speed + speed_step, …, max_speed`` in reference frames per
  query frame (mirrored to negative speeds with ``reverse``). Each query frame the speed stays,
  or with probability ``speed_change`` moves to a neighbouring grid speed (a random walk: the
  vehicle accelerates gradually); with ``reverse``, ``direction_change`` flips its sign.
- **motion**: a state at frame ``i`` with speed ``v`` moves to ``i + v`` (a fractional ``v``
  splits its mass between the two nearest frames). Mass driven off either end of the route
  leaves it.
- **relocalisation**: with probability ``relocalization`` the vehicle may be anywhere (a uniform
  jump), so the filter recovers when it has lost track or the vehicle was moved.
- **emission**: one query's frame log-scores ``L`` (``(N,)``, from a model's
  ``frame_log_scores``). With ``emission="zscore"`` (default) they are standardised per query,
  ``(L − mean L) / std L`` over the frames the model scored, and multiplied by
  ``emission_scale``: the filter then needs no per-model calibration (it is invariant to any
  positive affine change of the scores). ``emission="raw"`` uses ``emission_scale · L``, for
  calibrated log-likelihoods. A frame the model did not score (``−inf``, e.g. outside a
  chunked model's top chunks) gets the lowest score the model gave, so one query cannot veto.

One update costs ``O(S·N)`` for ``S`` grid speeds (a few array passes; nothing depends on how
many frames came before): the posterior lives in linear space rescaled to sum 1 each frame,
which is stable because the uniform jump keeps every predicted probability ``≥ ε/(S·N)``.

The estimate is the frame with the largest posterior (speeds marginalised); its confidence is
the posterior mass within ``confidence_radius`` frames of it.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from service.errors import InvalidInputError, InvalidParameterError

MAX_SPEEDS = 64  # grid speeds per direction
_BLOCK = 256  # query rows scored per model call in :func:`sequence_localize`, at most
_SCORE_BUDGET = 1 << 22  # … and at most this many frame scores (32 MiB of float64) per call
_FLAT = 1e-10  # a row whose spread is below this fraction of its magnitude is flat
_WORKSPACE_SHAPES = 4  # scratch kept per thread for this many route sizes
_MIN_LOG_LIKELIHOOD = -60.0  # one frame shrinks a state by at most e⁻⁶⁰ (float32 stays normal)


class SequenceConfig(BaseModel):
    """Parameters of a sequence filter, each with a validated range. The defaults are the best
    measured on the validation half of Nordland (``gridplace bench sequence``: exact NN and
    gridplace, drives at several speeds and a kidnapped vehicle); only the speed range is a
    prior on the vehicle, widen it for a vehicle that is faster relative to the map."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    min_speed: float = Field(
        0.5, ge=0.0, le=50.0, description="slowest speed, frames per query frame"
    )
    max_speed: float = Field(
        2.0, ge=0.0, le=50.0, description="fastest speed, frames per query frame"
    )
    speed_step: float = Field(0.25, gt=0.0, le=50.0, description="spacing of the speed grid")
    speed_change: float = Field(
        0.01, ge=0.0, le=1.0, description="probability per frame of moving to a neighbouring speed"
    )
    reverse: bool = Field(False, description="the vehicle may drive the route backwards")
    direction_change: float = Field(
        0.001, ge=0.0, le=1.0, description="probability per frame of reversing (with reverse)"
    )
    stop_probability: float = Field(
        0.0, ge=0.0, le=0.5, description="probability per frame of stopping (0: no stopped state)"
    )
    start_probability: float = Field(
        0.2, gt=0.0, le=1.0, description="probability per frame that a stopped vehicle moves on"
    )
    relocalization: float = Field(
        1e-4, gt=0.0, le=1.0, description="probability per frame of a jump anywhere on the route"
    )
    emission: Literal["zscore", "raw"] = Field(
        "zscore", description="zscore: standardise each query's frame scores; raw: use them as is"
    )
    emission_scale: float = Field(0.1, gt=0.0, le=1e6, description="weight of one query's evidence")
    confidence_radius: int = Field(
        5, ge=0, le=10_000, description="confidence = posterior mass within this many frames"
    )

    @model_validator(mode="after")
    def _speeds(self) -> SequenceConfig:
        if self.max_speed < self.min_speed:
            raise ValueError(f"max_speed {self.max_speed} is below min_speed {self.min_speed}")
        if self.max_speed - self.min_speed > (MAX_SPEEDS - 1 + 1e-6) * self.speed_step:
            raise ValueError(  # compared without dividing: a tiny step must not overflow
                f"the speed grid {self.min_speed}…{self.max_speed} by {self.speed_step} has more "
                f"than {MAX_SPEEDS} speeds (raise speed_step)"
            )
        return self

    @classmethod
    def parse(cls, **kwargs: Any) -> SequenceConfig:
        """Like the constructor, but raises :class:`InvalidParameterError`."""
        try:
            return cls(**kwargs)
        except ValidationError as exc:
            msgs = "; ".join(
                f"{'.'.join(str(p) for p in e['loc']) or 'config'}: {e['msg']}"
                for e in exc.errors()
            )
            raise InvalidParameterError(f"invalid sequence filter parameters: {msgs}") from exc

    @property
    def n_states(self) -> int:
        """Rows of a filter's state: grid speeds (both directions with ``reverse``), plus the
        stopped state when ``stop_probability > 0``; one update costs ``O(n_states · N)``."""
        return int(self.speeds().size) + int(self.stop_probability > 0)

    def speeds(self) -> np.ndarray:
        """The speed grid (ascending; negative speeds too with ``reverse``)."""
        n = int(np.floor((self.max_speed - self.min_speed) / self.speed_step + 1e-9)) + 1
        v = self.min_speed + self.speed_step * np.arange(n)
        if self.reverse:
            v = np.concatenate([-v[::-1], v])
        return v


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


class _Workspace(threading.local):
    """Scratch arrays shared by every filter of one thread (per-vehicle memory is the posterior
    alone: ``4·S·N`` bytes), for the few most recently used state shapes (maps)."""

    def __init__(self) -> None:
        self.arrays: OrderedDict[tuple[int, int], tuple[np.ndarray, np.ndarray]] = OrderedDict()

    def get(self, shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
        bufs = self.arrays.get(shape)
        if bufs is None:
            bufs = (np.empty(shape, dtype=np.float32), np.empty(shape, dtype=np.float32))
            self.arrays[shape] = bufs
            while len(self.arrays) > _WORKSPACE_SHAPES:
                self.arrays.popitem(last=False)
        self.arrays.move_to_end(shape)
        return bufs


_WORKSPACE = _Workspace()


class SequenceFilter:
    """One vehicle's recursive Bayes filter over a route of ``n_frames`` frames."""

    def __init__(self, n_frames: int, config: SequenceConfig | None = None) -> None:
        if int(n_frames) < 1:
            raise InvalidParameterError(f"a route has at least one frame, got {n_frames}")
        self.n_frames = int(n_frames)
        self.config = config or SequenceConfig()
        v = self.config.speeds()
        n_dir = v.size // 2 if self.config.reverse else v.size  # speeds per direction
        self._stop: int | None = None
        if self.config.stop_probability > 0:  # a stopped state, between the two directions
            self._stop = n_dir if self.config.reverse else 0
            v = np.insert(v, self._stop, 0.0)
        self.speeds = v  # ascending: rows that share the integer part of a speed are contiguous
        first = [0, n_dir + (self._stop is not None)] if self.config.reverse else [v.size - n_dir]
        self._blocks = [slice(lo, lo + n_dir) for lo in first]  # each direction's speed grid
        whole = np.floor(v).astype(np.int64)
        frac = (v - whole).astype(np.float32)
        # rows that share the integer part of their speed are shifted by one slice operation
        self._groups = [
            (
                int(a),
                slice(int(idx[0]), int(idx[-1]) + 1),
                (1 - frac[idx])[:, None],
                frac[idx][:, None],
                bool(frac[idx].any()),
            )
            for a in np.unique(whole)
            for idx in [np.flatnonzero(whole == a)]
        ]
        self._post = np.empty((v.size, self.n_frames), dtype=np.float32)
        self.reset()

    def reset(self) -> None:
        """Forget the vehicle: every ``(speed, frame)`` equally likely."""
        self._post.fill(1.0 / self._post.size)
        self._mass = 1.0  # the stored posterior sums to this (normalised lazily)
        self._frames = 0

    @property
    def nbytes(self) -> int:
        """Memory this vehicle's state holds."""
        return int(self._post.nbytes)

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

    def update(self, frame_log_scores: np.ndarray) -> SequenceEstimate:
        """Fold in one query's frame log-scores ``(N,)`` and return the filtered estimate."""
        e = emission_log_likelihood(check_scores(frame_log_scores, self.n_frames), self.config)
        lik = np.exp(e, out=e).astype(np.float32)[None, :]
        if self._frames:
            eps = self.config.relocalization
            pred = self._predict()  # sums to (at most) 1: mass driven off the route is gone
            pred += np.float32(eps / ((1.0 - eps) * pred.size))  # the uniform jump, up to 1 − ε
            np.multiply(pred, lik, out=self._post)
        else:
            self._post *= lik
        self._frames += 1
        return self._estimate()

    def _predict(self) -> np.ndarray:
        """Speed change, then motion, of the normalised posterior (into a scratch array; the
        vehicle's own array is scratch afterwards)."""
        mixed, pred = _WORKSPACE.get(self._post.shape)
        self._change_speed(self._post, mixed, pred, 1.0 / self._mass)
        scratch, N = self._post, self.n_frames
        for a, rows, keep, move, fractional in self._groups:
            _shift(pred[rows], mixed[rows], a, keep if fractional else None, N)
            if fractional:
                _shift_add(pred[rows], mixed[rows], a + 1, move, scratch[rows], N)
        return pred

    def _change_speed(
        self, post: np.ndarray, out: np.ndarray, tmp: np.ndarray, scale: float
    ) -> None:
        """``out = scale ·`` (speed random walk on each direction's grid with reflecting ends,
        stopping and moving on, then direction flips); ``tmp`` is scratch, ``post`` is left as
        it was."""
        cfg = self.config
        q = cfg.speed_change
        np.multiply(post, np.float32(scale * (1.0 - q)), out=out)  # float32 scalars: float32 loops
        h = np.float32(0.5 * q * scale)
        if q > 0:
            np.multiply(post, h, out=tmp)  # each neighbour's share
            for block in self._blocks:
                src, dst = tmp[block], out[block]
                if src.shape[0] > 1:
                    dst[1:] += src[:-1]
                    dst[:-1] += src[1:]
                    dst[0] += src[0]  # reflect: the missing neighbour's share stays
                    dst[-1] += src[-1]
                else:
                    dst += src
                    dst += src
        if self._stop is not None:
            stopped = np.multiply(post[self._stop], np.float32(scale), out=tmp[self._stop])
            moving = sum(out[block].sum(axis=0) for block in self._blocks)
            go, halt = cfg.start_probability, cfg.stop_probability
            share = stopped * np.float32(go / sum(b.stop - b.start for b in self._blocks))
            for block in self._blocks:
                out[block] *= np.float32(1.0 - halt)
                out[block] += share
            np.multiply(stopped, np.float32(1.0 - go), out=out[self._stop])
            out[self._stop] += moving * np.float32(halt)
        if self.config.reverse:
            r = self.config.direction_change
            np.multiply(out[::-1], np.float32(r), out=tmp)  # speed v ↔ −v: the grid is mirrored
            out *= np.float32(1.0 - r)
            out += tmp

    def _estimate(self) -> SequenceEstimate:
        marginal = self._post.sum(axis=0)
        self._mass = float(marginal.sum(dtype=np.float64))
        best = int(np.argmax(marginal))
        r = self.config.confidence_radius
        near = float(marginal[max(0, best - r) : best + r + 1].sum(dtype=np.float64))
        conf = min(1.0, near / self._mass)
        at_best = self._post[:, best].astype(np.float64)
        speed = float(self.speeds @ at_best / at_best.sum())  # mean speed at the estimated frame
        return SequenceEstimate(best, conf, float(np.log(max(conf, 1e-300))), self._frames, speed)


def _shift(dst: np.ndarray, src: np.ndarray, a: int, w: np.ndarray | None, n: int) -> None:
    """``dst[:, i] = w · src[:, i − a]`` (0 where the source lies off the route)."""
    if abs(a) >= n:
        dst.fill(0.0)
        return
    d, s = (slice(a, n), slice(0, n - a)) if a >= 0 else (slice(0, n + a), slice(-a, n))
    if w is None:
        dst[:, d] = src[:, s]
    else:
        np.multiply(src[:, s], w, out=dst[:, d])
    if a >= 0:
        dst[:, :a] = 0.0
    else:
        dst[:, n + a :] = 0.0


def _shift_add(
    dst: np.ndarray, src: np.ndarray, a: int, w: np.ndarray, tmp: np.ndarray, n: int
) -> None:
    """``dst[:, i] += w · src[:, i − a]`` where the source lies on the route (``tmp``: scratch)."""
    if abs(a) >= n:
        return
    d, s = (slice(a, n), slice(0, n - a)) if a >= 0 else (slice(0, n + a), slice(-a, n))
    np.multiply(src[:, s], w, out=tmp[:, d])
    dst[:, d] += tmp[:, d]


@dataclass(frozen=True)
class SequenceTrack:
    """Per-frame answers of one drive (all arrays have one entry per query frame)."""

    index: np.ndarray  # int64 filtered estimate
    confidence: np.ndarray  # float64
    speed: np.ndarray  # float64 posterior mean speed
    raw_index: np.ndarray  # int64 each frame's own best frame (argmax of its scores)

    def __len__(self) -> int:
        return int(self.index.shape[0])


ScoreFn = Callable[[np.ndarray], np.ndarray]


def filter_sequence(scores: np.ndarray, config: SequenceConfig | None = None) -> SequenceTrack:
    """Run one fresh filter over a drive's frame scores ``(T, N)`` (rows in driving order)."""
    S = np.asarray(scores)
    if S.ndim != 2 or S.shape[0] == 0:
        raise InvalidInputError(f"expected frame scores of shape (T, N) with T >= 1, got {S.shape}")
    filt = SequenceFilter(S.shape[1], config)
    return _run(filt, (S[t] for t in range(S.shape[0])), S.shape[0])


def sequence_localize(
    model: Any, queries: Any, config: SequenceConfig | None = None, block: int | None = None
) -> SequenceTrack:
    """Localize ``queries`` (rows in driving order) as one drive on a fitted model that has
    ``frame_log_scores`` (every model of :mod:`service.encoding`). Frame scores are computed
    ``block`` rows at a time (default: as many as fit ``_SCORE_BUDGET`` values, at most 256),
    so memory stays bounded for any drive and route length."""
    if not hasattr(model, "frame_log_scores"):
        raise InvalidParameterError(f"{type(model).__name__} gives no frame scores")
    Q = np.asarray(queries)
    if Q.ndim != 2 or Q.shape[0] == 0:
        raise InvalidInputError(
            f"expected query descriptors of shape (T, d) with T >= 1, got {Q.shape}"
        )
    n_frames = int(model.n_frames_)
    filt = SequenceFilter(n_frames, config)
    rows_per_call = block or max(1, min(_BLOCK, _SCORE_BUDGET // n_frames))

    def rows() -> Any:
        for s in range(0, Q.shape[0], rows_per_call):
            yield from model.frame_log_scores(Q[s : s + rows_per_call])

    return _run(filt, rows(), Q.shape[0])


def _run(filt: SequenceFilter, rows: Any, n: int) -> SequenceTrack:
    index = np.empty(n, dtype=np.int64)
    raw = np.empty(n, dtype=np.int64)
    conf = np.empty(n)
    speed = np.empty(n)
    for t, row in enumerate(rows):
        est = filt.update(row)
        index[t], conf[t], speed[t] = est.index, est.confidence, est.speed
        raw[t] = int(np.argmax(row))
    return SequenceTrack(index, conf, speed, raw)

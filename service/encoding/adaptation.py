"""Appearance adaptation: standardise a drive's queries by the drive's own running statistics.

A model z-scores every query with the column mean ``μ`` and standard deviation ``σ`` of the
reference traversal. Another season, time of day or camera shifts and rescales every column
(a winter drive is brighter and flatter than the summer map), and that shift, common to all of
the drive's frames, then weighs on the scores as much as the place does. A drive's frames
arrive in order, so each vehicle can keep an exponential running mean ``m`` and variance ``v``
of its own descriptors and hand the model ``x̃ = μ + σ·(x − m)/√v`` instead of ``x``: the
model's z-score of ``x̃`` is ``(x − m)/√v``, the frame standardised by its own drive.

It is causal and uses no position: frame ``t`` is standardised with the statistics of frames
``< t`` (starting from the route's own, so the first frame goes through unchanged), then
updates them. ``alpha`` is the weight of the newest frame (a memory of about ``1/alpha``
frames). Only a *new* scene updates them: a frame whose mean squared difference per column from
the last frame learnt from is below ``novelty`` running variances is answered but not learnt
from, so a stopped vehicle or a densely sampled video does not pull the statistics onto the
scene in front of it (two unrelated frames differ by about 2). The memory is then about
``1/alpha`` distinct scenes rather than frames.

The statistics are robust to outliers. A frame whose mean squared z-score ``mean((x − m)²/v)``
exceeds ``outlier`` (a frame of the drive scores about 1; the largest seen on Nordland's tuning
half was 3 for CNN descriptors and 9 for raw pixels) is answered but not learnt from, whatever
its values (a glitched camera frame, an all-1e6 descriptor); and a frame that is learnt from
moves each column by at most ``clip`` running standard deviations (a Huber-type update), so
one frame can shift a column's mean by at most ``alpha·clip`` of its spread and inflate its
variance by at most the factor ``(1 − alpha)(1 + alpha·clip²)`` (1.29 at the defaults), after
which the next frames of the drive still pass the novelty test and wash it out geometrically.
When ``patience`` frames in a row are outliers the drive has changed, not one frame (a new
camera, a vehicle whose statistics were wrong): the running mean restarts at the current
frame with the route's spread, and the drive is learnt from there.

The defaults were chosen on the tuning half of Nordland (winter frames 0–1,787 against the
summer map), CNN and raw-pixel descriptors alike, ``alpha`` among 0.005–0.1: precision within
±5 frames of the ``robust`` preset went from 52.9 % to 64.4 % (CNN) and from 24.2 % to 52.3 %
(pixels). The ``novelty`` rule (chosen among 0, 0.25, 0.5 and 1) was a tie there (+0.9 points
on CNN, −0.9 on pixels against learning from every frame) and decides the drives that tuning
half does not have: the same drive slowed ten-fold (every frame sent ten times) keeps 64.4 %
with it and drops to 59.2 % without; a drive interpolated ten-fold between its frames gets
60.0 % against 54.9 % (46.4 % unadapted). The robust rule was chosen there too: ``clip``
among 2, 3, 4 and none (−0.44, −0.11, −0.05 and 0 points on CNN; −2.29, −0.17, −0.06 and 0 on
pixels: one frame in 1,788 at 4, against unbounded influence without), ``outlier`` 25 or 100
(no frame of either drive reaches 25); one all-1e6 frame at position 10 took the rest of the
drive from 64.4 % to 0 % before and changes no answer now (docs/RESULTS.md). The standard deviation
a column may be divided by is floored at ``MIN_SCALE_RATIO·σ`` so that a column that stays
constant in one drive (a saturated sky) is not blown up.

A drive may start from a recorded condition's statistics instead of the route's
(:meth:`AppearanceAdapter.start_from`, :mod:`service.encoding.conditions`), named or inferred
from its first frames.

Works with any model whose front-end keeps the route's statistics (:meth:`for_model`), or
with statistics of a reference array (:meth:`for_reference`, e.g. for a baseline). Adapters of
one model share its route statistics; each holds only its own ``3·d`` float32 values
(:attr:`AppearanceAdapter.nbytes` counts them with the object's own overhead).
:func:`transform_rows` adapts the frames of many vehicles in one vectorised step per frame
position (a micro-batch of a fleet), with the answers of each adapter's own :meth:`transform`.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from service.encoding.conditions import (
    DEFAULT_INFERENCE_FRAMES,
    REFERENCE,
    ConditionInference,
    ConditionSet,
)
from service.encoding.adaptation_step import LAST as _LAST
from service.encoding.adaptation_step import MEAN as _MEAN
from service.encoding.adaptation_step import step
from service.encoding.adaptation_step import VAR as _VAR
from service.encoding.normalization import Normalizer
from service.encoding.route_statistics import RouteStatistics, route_statistics, shared_route
from service.errors import InvalidParameterError

DEFAULT_ALPHA = 0.02
DEFAULT_NOVELTY = 1.0
DEFAULT_CLIP = 4.0
DEFAULT_OUTLIER = 100.0
DEFAULT_PATIENCE = 8
#: Python-side bytes of one adapter beyond its state array (the object, its attribute dict and
#: the array's header), measured with tracemalloc (tests/unit/test_adaptation_memory.py)
ADAPTER_OVERHEAD_BYTES = 800


class AdaptationConfig(BaseModel):
    """Parameters of appearance adaptation (validated at the boundaries that take them)."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    alpha: float = Field(
        DEFAULT_ALPHA, gt=0.0, le=1.0,
        description="weight of the newest frame in the drive's running mean and variance",
    )  # fmt: skip
    novelty: float = Field(
        DEFAULT_NOVELTY, ge=0.0, le=100.0,
        description="a frame updates the statistics only if its mean squared difference per "
        "column from the last frame that did, in units of the running variance, is at least "
        "this (two unrelated frames differ by about 2; 0: every frame updates them)",
    )  # fmt: skip
    clip: float = Field(
        DEFAULT_CLIP, gt=0.0, le=1e6,
        description="a learnt frame moves each column by at most this many running standard "
        "deviations (Huber-type update)",
    )  # fmt: skip
    outlier: float = Field(
        DEFAULT_OUTLIER, gt=0.0, le=1e12,
        description="a frame whose mean squared z-score against the running statistics exceeds "
        "this is answered but not learnt from (a frame of the drive scores about 1)",
    )  # fmt: skip
    patience: int = Field(
        DEFAULT_PATIENCE, ge=2, le=10_000,
        description="this many outlying frames in a row restart the running mean at the "
        "current frame (the drive changed)",
    )  # fmt: skip


def adapts(model: Any, requested: bool | None, default: bool, what: str = "this model") -> bool:
    """Whether queries to ``model`` are adapted: as ``requested``, or ``default`` when not
    said. A model without route statistics has nothing to adapt to: it goes unadapted by
    default and is refused (naming ``what``) when adaptation was asked for explicitly."""
    if not (default if requested is None else requested):
        return False
    if route_statistics(model) is not None:
        return True
    if requested:
        raise InvalidParameterError(
            f"{what} was trained without normalisation and keeps no route statistics to adapt "
            "to; ask without adaptation"
        )
    return False


class AppearanceAdapter:
    """One drive's running statistics; :meth:`transform` its frames in drive order."""

    def __init__(self, mean: np.ndarray | RouteStatistics, scale: np.ndarray | None = None,
                 config: AdaptationConfig | None = None) -> None:  # fmt: skip
        self.config = config or AdaptationConfig()
        if isinstance(mean, RouteStatistics):
            self.route = mean
        else:
            if scale is None:
                raise InvalidParameterError("route statistics need a scale per mean")
            self.route = RouteStatistics.of(mean, scale)
        self._state = np.empty((3, self.route.mean.shape[0]), dtype=np.float32)
        self.conditions: ConditionSet | None = None  # the recorded conditions it may start from
        self.condition = 0  # the row of ``conditions`` it started from (0: the route's own)
        self._inference: ConditionInference | None = None
        self.reset()

    @classmethod
    def for_model(cls, model: Any, config: AdaptationConfig | None = None) -> AppearanceAdapter:
        stats = route_statistics(model)
        if stats is None:
            raise InvalidParameterError(
                "appearance adaptation needs the route's column statistics, and this model "
                "keeps none (it was trained without normalisation)"
            )
        return cls(shared_route(stats), config=config)

    @classmethod
    def for_reference(cls, X: np.ndarray, config: AdaptationConfig | None = None) -> AppearanceAdapter:
        stats = Normalizer.fit(np.asarray(X))
        return cls(stats.mean, stats.scale, config)

    @property
    def route_mean(self) -> np.ndarray:
        return self.route.mean

    @property
    def route_scale(self) -> np.ndarray:
        return self.route.scale

    @property
    def n_features(self) -> int:
        return int(self.route.mean.shape[0])

    @property
    def frames(self) -> int:
        """Frames seen since the start or the last :meth:`reset`."""
        return self._frames

    @property
    def learnt(self) -> int:
        """Frames the statistics learnt from since the start or the last :meth:`reset`."""
        return self._learnt

    @property
    def outliers(self) -> int:
        """Frames answered but not learnt from as outliers since the start or :meth:`reset`."""
        return self._outliers

    @property
    def nbytes(self) -> int:
        """Memory this adapter holds on its own: the running mean, variance and last frame
        learnt from (``3·d`` float32) and the Python objects around them (the route's
        statistics are shared by every adapter of the model and not counted here)."""
        vote = 0 if self._inference is None else self._inference.nbytes
        return int(self._state.nbytes) + ADAPTER_OVERHEAD_BYTES + vote

    def start_from(self, conditions: ConditionSet, condition: int | None,
                   frames: int = DEFAULT_INFERENCE_FRAMES) -> AppearanceAdapter:  # fmt: skip
        """Start the drive from a recorded condition's statistics (``condition``: its row in
        ``conditions``) instead of the route's, or with ``None`` from the condition its first
        ``frames`` frames are closest to (:class:`~service.encoding.conditions.ConditionInference`;
        until then from the closest so far). Resets the drive."""
        if conditions.mean.shape[1] != self.n_features:
            raise InvalidParameterError("the conditions hold statistics of another width")
        self.conditions = conditions
        self._inference = None if condition is not None else ConditionInference(conditions, frames)
        self.condition = 0 if condition is None else condition
        self.reset()
        return self

    @property
    def condition_name(self) -> str:
        """The condition the drive is standardised from (``reference``: the route's own)."""
        return REFERENCE if self.conditions is None else self.conditions.names[self.condition]

    @property
    def inferring(self) -> bool:
        """Whether the condition is (being) inferred from the drive's frames."""
        return self._inference is not None

    def reset(self) -> None:
        """Forget the drive: the next frame starts from the statistics of the condition it
        starts from (the route's own unless :meth:`start_from` said otherwise)."""
        if self._inference is not None:
            self._inference = ConditionInference(self._inference.conditions, self._inference.frames)
            self.condition = 0
        mean, var = self._seed(self.condition)
        self._state[_MEAN] = mean
        self._state[_VAR] = var
        self._state[_LAST] = mean
        self._seed_weight = 1.0  # the weight the starting statistics still have in the state
        self._has_last = False  # whether _state[_LAST] holds the last frame learnt from
        self._run = 0  # outlying frames in a row
        self._frames = self._learnt = self._outliers = 0

    def transform(self, X: np.ndarray) -> np.ndarray:
        """Adapted ``(n, d)`` float32 rows of validated descriptors ``X`` taken as the drive's
        next ``n`` frames, in row order; the statistics move on by ``n`` frames."""
        X = self._rows(X)
        out = np.empty_like(X)
        state = self._state[None]  # a (1, 3, d) view: the step updates the adapter in place
        for t in range(X.shape[0]):
            self._infer(X[t])
            out[t] = step(self.route, self.config, state, X[t : t + 1], [self])[0]
        return out

    def _seed(self, i: int) -> tuple[np.ndarray, np.ndarray]:
        if self.conditions is None or i == 0:
            return self.route.mean, self.route.var
        return self.conditions.mean[i], np.maximum(self.conditions.var[i], self.route.floor)

    def _infer(self, row: np.ndarray) -> None:
        """While the condition is being inferred, let ``row`` (the next frame) vote; when the
        closest condition changes, the starting statistics' remaining weight in the running
        ones moves to it (what starting from it would have given, to first order)."""
        vote = self._inference
        if vote is None or vote.decided:
            return
        choice = vote.observe(row)
        if choice != self.condition:
            self._move_seed(choice)

    def use_condition(self, i: int) -> None:
        """Go on as if the drive had started from condition ``i`` of :attr:`conditions`
        (inference, if any, stops)."""
        if self.conditions is None or not 0 <= i < len(self.conditions):
            raise InvalidParameterError(f"no condition {i} to start from")
        self._inference = None
        if i != self.condition:
            self._move_seed(i)

    def _move_seed(self, i: int) -> None:
        (m0, v0), (m1, v1) = self._seed(self.condition), self._seed(i)
        w = np.float32(self._seed_weight)
        self._state[_MEAN] += w * (m1 - m0)
        self._state[_VAR] = np.maximum(self._state[_VAR] + w * (v1 - v0), self.route.floor)
        if not self._has_last:
            self._state[_LAST] = self._state[_MEAN]
        self.condition = i

    def _rows(self, X: np.ndarray) -> np.ndarray:
        with np.errstate(over="ignore"):  # a value beyond float32 is infinite: an outlier
            X = np.atleast_2d(np.asarray(X, dtype=np.float32))
        if X.shape[1] != self.n_features:
            raise InvalidParameterError(
                f"the adapter holds statistics of d={self.n_features}, got rows of d={X.shape[1]}"
            )
        return X


def transform_rows(adapters: Sequence[AppearanceAdapter],
                   rows: Sequence[np.ndarray] | np.ndarray) -> list[np.ndarray]:  # fmt: skip
    """``rows[i]`` (one frame, ``d`` values) adapted as the next frame of ``adapters[i]``'s
    drive, rows in drive order (an adapter may appear several times: its rows are taken in
    order; adapters of different routes may be mixed). Equal to each adapter's own
    :meth:`~AppearanceAdapter.transform` of its rows; adapters that share route statistics and
    configuration are stepped together, one vectorised step per position."""
    if len(rows) != len(adapters):
        raise InvalidParameterError(f"{len(adapters)} adapters for {len(rows)} rows")
    out: list[np.ndarray] = [np.empty(0)] * len(adapters)
    groups: dict[tuple[int, AdaptationConfig], list[int]] = {}
    for i, a in enumerate(adapters):
        groups.setdefault((id(a.route), a.config), []).append(i)
    for members in groups.values():
        first = adapters[members[0]]
        for i in members:
            if np.size(rows[i]) != first.n_features:
                first._rows(np.ravel(rows[i]))  # raises, naming both widths
        X = first._rows(np.stack([np.ravel(rows[i]) for i in members]) if len(members) > 1
                        else rows[members[0]])  # fmt: skip
        local = {i: k for k, i in enumerate(members)}
        for position in _positions(adapters, members):
            group = [adapters[i] for i in position]
            at = [local[i] for i in position]
            for a, k in zip(group, at, strict=True):
                a._infer(X[k])
            if len(position) == 1:
                got = step(first.route, first.config, group[0]._state[None], X[at], group)
            else:
                state = np.stack([a._state for a in group])
                got = step(first.route, first.config, state, X[at], group)
                for a, s in zip(group, state, strict=True):
                    a._state[...] = s
            for i, row in zip(position, got, strict=True):
                out[i] = row
    return out


def _positions(adapters: Sequence[AppearanceAdapter], rows: list[int]) -> list[list[int]]:
    """``rows`` split into steps: the k-th step holds each adapter's k-th row."""
    seen: dict[int, int] = {}
    steps: list[list[int]] = []
    for i in rows:
        k = seen.get(id(adapters[i]), 0)
        seen[id(adapters[i])] = k + 1
        if k == len(steps):
            steps.append([])
        steps[k].append(i)
    return steps


def adapt_drive(model: Any, X: np.ndarray, config: AdaptationConfig | None = None,
                start: AppearanceAdapter | None = None) -> np.ndarray:  # fmt: skip
    """``X`` adapted as one drive in row order against ``model``'s route statistics (by
    ``start``, a fresh adapter of the model, e.g. one started from a condition)."""
    return (start or AppearanceAdapter.for_model(model, config)).transform(X)

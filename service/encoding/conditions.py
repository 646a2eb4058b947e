"""Condition statistics: the appearance of each condition a map was given traversals in.

An appended traversal tagged with a condition (``season=winter``) leaves its column mean ``m``
and variance ``v`` in the model, beside the route's own (the reference traversal's ``μ``,
``σ²``, which the model normalises every query with). A query that names the condition it was
taken in is standardised by that condition's statistics instead of passing unchanged:
``x̃ = μ + σ·(x − m)/√v``, so the model's z-score of ``x̃`` is ``(x − m)/√v``, the frame
standardised as its own condition's frames are (one query, no history needed). A drive's
appearance adapter (:mod:`service.encoding.adaptation`) starts from the named condition's
statistics instead of the route's, so its first frames are answered as if it had already
driven ``1/alpha`` frames in that condition.

When no condition is named, the closest recorded one is *inferred*: each condition is a
diagonal Gaussian ``N(m, v)`` over the descriptor's columns, and the frames seen so far vote
with their summed log-likelihoods (:class:`ConditionInference`); after ``frames`` frames
(default 8) the choice is fixed for the drive. On Nordland's CNN descriptors one frame
alone picks the right season for 87.5 % of the winter frames of the test half (98.7 % of the
summer ones); see docs/RESULTS.md (Map lifecycle) for what each choice does to precision.

Every condition's variance is floored at the route's (``MIN_SCALE_RATIO·σ``)², as the
adapter floors its own, so a column constant in one condition is not blown up.
"""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from types import MappingProxyType
from typing import Any

import numpy as np

from service.encoding.adaptation_step import MIN_SCALE_RATIO
from service.encoding.normalization import column_moments
from service.errors import InvalidInputError, InvalidParameterError

REFERENCE = "reference"  #: the route's own statistics (the traversal(s) it was trained on)
AUTO = "auto"  #: infer the closest recorded condition from the frames
MAX_CONDITIONS = 64  # recorded conditions per model (the reference not counted)
DEFAULT_INFERENCE_FRAMES = 8
MAX_INFERENCE_FRAMES = 1024
_BLOCK_ROWS = 4096
# a condition's key: key=value tags, sorted, joined by ',' (the form appends record)
_KEY = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,63}=[^=]{1,200}(,[A-Za-z0-9][A-Za-z0-9_.-]{0,63}=[^=,]{1,200})*$")


class UnknownConditionError(InvalidInputError):
    """A query named a condition the map version records no statistics of (400)."""

    code = "unknown_condition"


def condition_key(tags: Mapping[str, str]) -> str | None:
    """The key a tag set's statistics are recorded under (``None`` for no tags): the tags
    ``key=value`` sorted by key and joined by commas, e.g. ``season=winter,time=night``."""
    if not tags:
        return None
    return ",".join(f"{k}={v}" for k, v in sorted(tags.items()))


def check_condition_key(key: str) -> str:
    if not isinstance(key, str) or len(key) > 4096 or _KEY.match(key) is None:
        raise InvalidParameterError(
            f"condition {key!r} is not key=value tags joined by ',' (e.g. season=winter)",
            condition=str(key)[:200],
        )  # fmt: skip
    return key


@dataclass(frozen=True)
class ConditionStats:
    """Column mean and (population) variance of a condition's rows, and how many rows."""

    mean: np.ndarray  # float64 (d,)
    var: np.ndarray  # float64 (d,)
    rows: int

    @classmethod
    def of(cls, X: np.ndarray) -> ConditionStats:
        """The statistics of ``X`` (``(n, d)``, n ≥ 1), in row blocks."""
        mean, var = column_moments(X, _BLOCK_ROWS)
        return cls(mean, var, int(X.shape[0]))

    def merged(self, other: ConditionStats) -> ConditionStats:
        """The statistics of both sets of rows together (Chan et al.'s pairwise update)."""
        n = self.rows + other.rows
        delta = other.mean - self.mean
        mean = self.mean + delta * (other.rows / n)
        m2 = self.var * self.rows + other.var * other.rows + delta**2 * (self.rows * other.rows / n)
        return ConditionStats(mean, m2 / n, n)

    def to_arrays(self, prefix: str) -> dict[str, np.ndarray]:
        return {f"{prefix}.mean": self.mean, f"{prefix}.var": self.var,
                f"{prefix}.rows": np.array([self.rows], np.int64)}  # fmt: skip

    @classmethod
    def from_arrays(cls, arrays: Mapping[str, np.ndarray], prefix: str) -> ConditionStats:
        mean = np.asarray(arrays[f"{prefix}.mean"], np.float64)
        var = np.asarray(arrays[f"{prefix}.var"], np.float64)
        rows = int(np.asarray(arrays[f"{prefix}.rows"])[0])
        if mean.shape != var.shape or mean.ndim != 1 or rows < 1 or not (var >= 0).all():
            raise ValueError(f"inconsistent condition statistics {prefix}")
        return cls(mean, var, rows)


def record(conditions: Mapping[str, ConditionStats] | None, key: str | None,
           X: np.ndarray) -> dict[str, ConditionStats]:  # fmt: skip
    """``conditions`` with ``X``'s statistics added under ``key`` (merged with any recorded
    there); unchanged (a copy) without a key."""
    out = dict(conditions or {})
    if key is None:
        return out
    check_condition_key(key)
    stats = ConditionStats.of(X)
    if key in out:
        out[key] = out[key].merged(stats)
    elif len(out) >= MAX_CONDITIONS:
        raise InvalidParameterError(
            f"the model records {len(out)} conditions, the most it keeps; append under one of "
            "them or without a condition", conditions=len(out),
        )  # fmt: skip
    else:
        out[key] = stats
    return out


def fitted_conditions(X: Any, keys: Sequence[str | None] | None) -> dict[str, ConditionStats]:
    """The conditions of a fit: traversal ``X[i]`` (an array, or a list of them) recorded
    under ``keys[i]`` (``None``: not recorded); ``{}`` without keys."""
    if keys is None:
        return {}
    from service.encoding.traversals import is_several

    parts = list(X) if is_several(X) else [X]
    if len(keys) != len(parts):
        raise InvalidParameterError(
            f"{len(parts)} traversals need {len(parts)} conditions (one per traversal, None "
            f"for none), got {len(keys)}", traversals=len(parts), conditions=len(keys),
        )  # fmt: skip
    out: dict[str, ConditionStats] = {}
    for part, key in zip(parts, keys, strict=True):
        out = record(out, key, np.asarray(part))
    return out


def conditions_of_rows(X: np.ndarray, ranges: Mapping[str, Sequence[Sequence[int]]]) -> dict[str, ConditionStats]:
    """The conditions of a route's rows: each key's statistics over its ``[start, stop)``
    row ranges of ``X`` (a retrain's tagged traversals)."""
    out: dict[str, ConditionStats] = {}
    for key, spans in ranges.items():
        for start, stop in spans:
            if not 0 <= start < stop <= X.shape[0]:
                raise InvalidParameterError(f"condition {key!r} rows {start}…{stop} are not "
                                            f"rows of the route's {X.shape[0]}")  # fmt: skip
            out = record(out, key, np.asarray(X[start:stop]))
    return out


def conditions_to_arrays(conditions: Mapping[str, ConditionStats], arrays: dict[str, np.ndarray],
                         prefix: str = "") -> list[str]:  # fmt: skip
    """Add arrays ``{prefix}cond.{i}.*`` to ``arrays``; returns the keys in their order (kept
    in the manifest's meta)."""
    keys = sorted(conditions)
    for i, key in enumerate(keys):
        arrays.update(conditions[key].to_arrays(f"{prefix}cond.{i}"))
    return keys


def conditions_from_arrays(arrays: Mapping[str, np.ndarray], keys: Any,
                           prefix: str = "") -> dict[str, ConditionStats]:  # fmt: skip
    if not keys:
        return {}
    if not isinstance(keys, list) or len(keys) > MAX_CONDITIONS:
        raise ValueError(f"the manifest's condition keys are not a list of at most {MAX_CONDITIONS}")
    return {check_condition_key(k): ConditionStats.from_arrays(arrays, f"{prefix}cond.{i}")
            for i, k in enumerate(keys)}  # fmt: skip


@dataclass(frozen=True, eq=False)
class ConditionSet:
    """Every condition of one model as float32 arrays (row 0: the reference), floored, with
    what the log-likelihood of a frame needs; shared by every query of the model."""

    names: tuple[str, ...]
    mean: np.ndarray  # (C, d) float32
    var: np.ndarray  # (C, d) float32, floored
    inv_var: np.ndarray  # (C, d) float32
    log_norm: np.ndarray  # (C,) float64: Σ log v

    @classmethod
    def build(cls, route_mean: np.ndarray, route_scale: np.ndarray,
              conditions: Mapping[str, ConditionStats]) -> ConditionSet:  # fmt: skip
        sigma = np.asarray(route_scale, np.float64)
        floor = (MIN_SCALE_RATIO * sigma) ** 2
        keys = sorted(conditions)
        mean = np.stack([np.asarray(route_mean, np.float64), *(conditions[k].mean for k in keys)])
        var = np.maximum(np.stack([sigma**2, *(conditions[k].var for k in keys)]), floor)
        arrays = [mean.astype(np.float32), var.astype(np.float32), (1.0 / var).astype(np.float32)]
        for a in arrays:
            a.flags.writeable = False
        return cls((REFERENCE, *keys), *arrays, np.log(var).sum(axis=1))

    def __len__(self) -> int:
        return len(self.names)

    def index(self, name: str) -> int:
        """The row of condition ``name``; :class:`UnknownConditionError` naming the known ones."""
        try:
            return self.names.index(name)
        except ValueError:
            known = ", ".join(self.names)
            raise UnknownConditionError(
                f"condition {name!r} is not recorded by this map version; known: {known} "
                f"(or {AUTO} to infer it)", condition=str(name)[:200], known=list(self.names),
            ) from None  # fmt: skip

    def log_likelihood(self, X: np.ndarray) -> np.ndarray:
        """``(n, C)``: each row's diagonal-Gaussian log-likelihood under each condition, up
        to a constant shared by all (``−½ Σ_j (x_j − m_j)²/v_j + log v_j``)."""
        X = np.asarray(X, np.float64)
        iv = self.inv_var.astype(np.float64)
        m = self.mean.astype(np.float64)
        quad = (X * X) @ iv.T - 2.0 * X @ (m * iv).T + np.einsum("cd,cd->c", m * m, iv)
        return -0.5 * (quad + self.log_norm)

    def standardise(self, i: int, X: np.ndarray, route_mean: np.ndarray,
                    route_scale: np.ndarray) -> np.ndarray:  # fmt: skip
        """``X`` standardised by condition ``i``: ``μ + σ·(x − m_i)/√v_i`` (the reference:
        ``X`` unchanged)."""
        if i == 0:
            return X
        dtype = X.dtype if X.dtype in (np.float32, np.float64) else np.float64
        root = np.sqrt(self.var[i]).astype(dtype)
        return (route_mean.astype(dtype) + route_scale.astype(dtype) * (X - self.mean[i].astype(dtype)) / root)


class ConditionInference:
    """One drive's vote for the closest condition: the summed log-likelihoods of its first
    ``frames`` finite frames; :attr:`choice` is the best so far and is final after them."""

    __slots__ = ("conditions", "frames", "seen", "total", "choice")

    def __init__(self, conditions: ConditionSet, frames: int = DEFAULT_INFERENCE_FRAMES) -> None:
        if not 1 <= frames <= MAX_INFERENCE_FRAMES:
            raise InvalidParameterError(f"condition inference takes 1–{MAX_INFERENCE_FRAMES} "
                                        f"frames, got {frames}")  # fmt: skip
        self.conditions = conditions
        self.frames = frames
        self.seen = 0
        self.total = np.zeros(len(conditions))
        self.choice = 0

    @property
    def decided(self) -> bool:
        return self.seen >= self.frames

    @property
    def nbytes(self) -> int:
        return int(self.total.nbytes) + 200

    def observe(self, X: np.ndarray) -> int:
        """Take the drive's next frames (rows in order, until decided) and return the choice."""
        for row in np.atleast_2d(X):
            if self.decided:
                break
            if not np.isfinite(row).all():
                continue  # an unusable frame votes for nothing
            with np.errstate(over="ignore", invalid="ignore"):
                ll = self.conditions.log_likelihood(row[None])[0]
            if not np.isfinite(ll).all():
                continue
            self.total += ll
            self.seen += 1
            self.choice = int(np.argmax(self.total))
        return self.choice


def infer(conditions: ConditionSet, X: np.ndarray) -> int:
    """The condition closest to all of ``X``'s finite rows together (the reference if none)."""
    total = np.zeros(len(conditions))
    for s in range(0, X.shape[0], _BLOCK_ROWS):
        with np.errstate(over="ignore", invalid="ignore"):
            ll = conditions.log_likelihood(X[s : s + _BLOCK_ROWS])
        total += ll[np.isfinite(ll).all(axis=1)].sum(axis=0)
    return int(np.argmax(total))


_NO_CONDITIONS: Mapping[str, ConditionStats] = MappingProxyType({})


def condition_set(model: Any) -> ConditionSet | None:
    """The conditions ``model`` records, with its reference first (``None``: it keeps no
    route statistics to standardise to); built once per recorded mapping and kept on the
    model (:meth:`partial_fit` replaces the mapping)."""
    from service.encoding.adaptation import route_statistics

    front = route_statistics(model)
    if front is None:
        return None
    recorded = getattr(model, "conditions_", None) or _NO_CONDITIONS
    cached = getattr(model, "_condition_set", None)
    if cached is not None and cached[0] is recorded and cached[1] is front:
        return cached[2]  # type: ignore[no-any-return]
    built = ConditionSet.build(front.mean, front.scale, recorded)
    model._condition_set = (recorded, front, built)
    return built

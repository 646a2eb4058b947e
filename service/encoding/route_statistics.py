"""The route's column statistics that appearance adaptation starts from and falls back to
(:mod:`service.encoding.adaptation`): a fitted model's normaliser, held once in float32 per
normaliser object however many adapters (vehicles) use it."""

from __future__ import annotations

import threading
import weakref
from dataclasses import dataclass
from typing import Any

import numpy as np

from service.encoding.adaptation_step import MIN_SCALE_RATIO
from service.encoding.normalization import Normalizer
from service.errors import InvalidParameterError


@dataclass(frozen=True, eq=False)
class RouteStatistics:
    """The route's column statistics in float32 (the precision models store them in), shared
    by every adapter of one model."""

    mean: np.ndarray
    scale: np.ndarray
    var: np.ndarray
    floor: np.ndarray  # the smallest variance a column is divided by

    @classmethod
    def of(cls, mean: np.ndarray, scale: np.ndarray) -> RouteStatistics:
        mu = np.array(mean, dtype=np.float32).ravel()
        sigma = np.array(scale, dtype=np.float32).ravel()
        if mu.shape != sigma.shape or not np.all(sigma > 0):
            raise InvalidParameterError("route statistics need one positive scale per mean")
        for a in (mu, sigma):
            a.flags.writeable = False
        var, floor = sigma**2, (MIN_SCALE_RATIO * sigma) ** 2
        var.flags.writeable = floor.flags.writeable = False
        return cls(mu, sigma, var, floor)

    @property
    def nbytes(self) -> int:
        return int(4 * self.mean.nbytes)


_shared: dict[int, tuple[weakref.ref[Normalizer], RouteStatistics]] = {}
_shared_lock = threading.Lock()


def shared_route(front: Normalizer) -> RouteStatistics:
    """One :class:`RouteStatistics` per normaliser object, for as long as it lives."""
    key = id(front)
    with _shared_lock:
        hit = _shared.get(key)
        if hit is not None and hit[0]() is front:
            return hit[1]
        route = RouteStatistics.of(front.mean, front.scale)
        _shared[key] = (weakref.ref(front, lambda _, key=key: _shared.pop(key, None)), route)
        return route


def route_statistics(model: Any) -> Normalizer | None:
    """The column statistics a fitted model normalises queries with (``None``: it has none,
    e.g. trained with ``normalize=False``)."""
    front = getattr(model, "normalizer_", None)
    if isinstance(front, Normalizer):
        return front
    return getattr(front, "normalizer", None)

"""Power-law fits ``y = c·x^a`` (the storage-scaling exponent of the paper's Table I)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from service.errors import InvalidParameterError


@dataclass(frozen=True)
class PowerLawFit:
    """Least-squares line through ``(log x, log y)``: ``log y = log c + a·log x``."""

    a: float  # exponent: 1 = linear storage growth, < 1 sub-linear
    c: float
    r2: float  # coefficient of determination in log space (1.0 with two points)
    n_points: int
    x_min: float
    x_max: float

    def predict(self, x: np.ndarray | float) -> np.ndarray:
        return self.c * np.power(np.asarray(x, dtype=np.float64), self.a)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def fit_power_law(x: Sequence[float] | np.ndarray, y: Sequence[float] | np.ndarray) -> PowerLawFit:
    """Fit ``y = c·x^a`` to positive points; needs at least two distinct ``x``."""
    xs = np.asarray(x, dtype=np.float64)
    ys = np.asarray(y, dtype=np.float64)
    if xs.shape != ys.shape or xs.ndim != 1:
        raise InvalidParameterError("x and y must be one-dimensional and of equal length")
    if xs.size < 2 or np.unique(xs).size < 2:
        raise InvalidParameterError("a power-law fit needs at least two distinct x values")
    if (xs <= 0).any() or (ys <= 0).any() or not np.isfinite(xs).all() or not np.isfinite(ys).all():
        raise InvalidParameterError("a power-law fit needs finite, positive x and y")
    lx, ly = np.log(xs), np.log(ys)
    a, log_c = np.polyfit(lx, ly, 1)
    resid = ly - (log_c + a * lx)
    total = float(np.sum((ly - ly.mean()) ** 2))
    r2 = 1.0 - float(np.sum(resid**2)) / total if total > 0 else 1.0
    return PowerLawFit(
        a=float(a), c=float(np.exp(log_c)), r2=r2, n_points=int(xs.size),
        x_min=float(xs.min()), x_max=float(xs.max()),
    )  # fmt: skip

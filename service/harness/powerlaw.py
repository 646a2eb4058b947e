"""Power-law fits of storage against route length, in two forms.

- :func:`fit_power_law`: ``y = c·x^a``, least squares in log space. The exponent is the
  growth rate: 1 for storage that is linear in N, whatever the constant.
- :func:`fit_paper_form`: the paper's Table I form, ``storage in MB = N^a`` with **no
  prefactor**, least squares in MB (as MATLAB's curve fitting does). Without ``c`` the
  exponent must also absorb the scale: for exactly linear storage of ``b`` bytes per frame it
  is about ``log(b·N/10⁶)/log N``, e.g. ≈ 0.53 for exact NN on 2,048 float64 columns over
  N = 100…10,000 — so a "sub-linear" a < 1 in this form says little about growth.
"""

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


def _points(x: Sequence[float] | np.ndarray, y: Sequence[float] | np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    xs = np.asarray(x, dtype=np.float64)
    ys = np.asarray(y, dtype=np.float64)
    if xs.shape != ys.shape or xs.ndim != 1:
        raise InvalidParameterError("x and y must be one-dimensional and of equal length")
    if xs.size < 2 or np.unique(xs).size < 2:
        raise InvalidParameterError("a power-law fit needs at least two distinct x values")
    if (xs <= 0).any() or (ys <= 0).any() or not np.isfinite(xs).all() or not np.isfinite(ys).all():
        raise InvalidParameterError("a power-law fit needs finite, positive x and y")
    return xs, ys


def fit_power_law(x: Sequence[float] | np.ndarray, y: Sequence[float] | np.ndarray) -> PowerLawFit:
    """Fit ``y = c·x^a`` to positive points; needs at least two distinct ``x``."""
    xs, ys = _points(x, y)
    lx, ly = np.log(xs), np.log(ys)
    a, log_c = np.polyfit(lx, ly, 1)
    resid = ly - (log_c + a * lx)
    total = float(np.sum((ly - ly.mean()) ** 2))
    r2 = 1.0 - float(np.sum(resid**2)) / total if total > 0 else 1.0
    return PowerLawFit(
        a=float(a), c=float(np.exp(log_c)), r2=r2, n_points=int(xs.size),
        x_min=float(xs.min()), x_max=float(xs.max()),
    )  # fmt: skip


MB = 1e6  # the paper's storage unit (bytes)


@dataclass(frozen=True)
class PaperFormFit:
    """``storage / MB = N^a`` (no prefactor), least squares in MB: the paper's Table I form."""

    a: float
    rmse_mb: float  # root-mean-square residual in MB
    n_points: int
    x_min: float
    x_max: float

    def predict_bytes(self, x: np.ndarray | float) -> np.ndarray:
        return MB * np.power(np.asarray(x, dtype=np.float64), self.a)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def fit_paper_form(x: Sequence[float] | np.ndarray, y_bytes: Sequence[float] | np.ndarray) -> PaperFormFit:
    """Fit ``y_bytes / 10⁶ = x^a`` by least squares in MB (a one-parameter problem)."""
    from scipy.optimize import least_squares

    xs, ys = _points(x, y_bytes)
    mb = ys / MB
    start = float(np.clip(np.median(np.log(mb) / np.log(xs)), -2.0, 2.0))
    fit = least_squares(lambda a: np.power(xs, a[0]) - mb, [start], bounds=([-3.0], [3.0]))
    a = float(fit.x[0])
    rmse = float(np.sqrt(np.mean((np.power(xs, a) - mb) ** 2)))
    return PaperFormFit(a=a, rmse_mb=rmse, n_points=int(xs.size), x_min=float(xs.min()),
                        x_max=float(xs.max()))  # fmt: skip

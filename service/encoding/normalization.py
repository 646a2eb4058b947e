"""Training-set z-scoring stored in the model and applied to every query.

The paper's code z-scored the reference and query sets each with their own statistics; a
service sees one query at a time, so the statistics of the route are part of the model.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from service.errors import InputOverflowError

_MIN_STD = 1e-8  # constant columns (black frames, borders) are centred, not divided by ~0
_FLOAT32_MAX = float(np.finfo(np.float32).max)


def column_moments(X: np.ndarray, block_rows: int = 8192) -> tuple[np.ndarray, np.ndarray]:
    """Column mean and population variance of ``X`` (``(n, d)``, n ≥ 1) in float64, two
    passes over row blocks (no full-size float64 temporary)."""
    n, d = X.shape
    total = np.zeros(d)
    for s in range(0, n, block_rows):
        total += X[s : s + block_rows].sum(axis=0, dtype=np.float64)
    mean = total / n
    sq = np.zeros(d)
    for s in range(0, n, block_rows):
        diff = np.asarray(X[s : s + block_rows], dtype=np.float64) - mean
        sq += np.einsum("ij,ij->j", diff, diff)
    return mean, sq / n


@dataclass(frozen=True)
class Normalizer:
    mean: np.ndarray  # float32, shape (d,)
    scale: np.ndarray  # float32, shape (d,), never 0

    @classmethod
    def fit(cls, X: np.ndarray, block_rows: int = 8192) -> Normalizer:
        """Column mean and standard deviation, in row blocks (no full-size temporary)."""
        mean, var = column_moments(X, block_rows)
        std = np.sqrt(var)
        std = np.where(std < _MIN_STD, 1.0, std)
        return cls(mean=mean.astype(np.float32), scale=std.astype(np.float32))

    def transform(self, X: np.ndarray) -> np.ndarray:
        """z-scores of ``X``; :class:`InputOverflowError` for values so far from the route's
        scale that a linear score over the ``d`` columns could overflow float32 (the precision
        of stored weights and of float32 queries): ``|z| ≤ float32 max / d``."""
        X = np.asarray(X, dtype=np.float64)
        with np.errstate(over="ignore", invalid="ignore"):
            Z = (X - self.mean.astype(np.float64)) / self.scale.astype(np.float64)
        limit = _FLOAT32_MAX / max(1, Z.shape[-1])
        if Z.size and not (-limit <= Z.min() and Z.max() <= limit):  # NaN fails both
            self._overflow(X, Z, limit)
        return Z

    def _overflow(self, X: np.ndarray, Z: np.ndarray, limit: float) -> None:
        X2, Z2 = np.atleast_2d(X), np.atleast_2d(Z)
        row, col = (int(i) for i in np.argwhere(~(np.abs(Z2) <= limit))[0])
        raise InputOverflowError(
            f"descriptors overflow once normalised with the route's statistics: row {row}, "
            f"column {col} is {X2[row, col]:.6g}, (x − mean)/std = {Z2[row, col]:.6g}, beyond "
            f"±{limit:.3g} (float32 max / d); send descriptors on the scale of the route's",
            row=row, column=col, limit=limit,
        )  # fmt: skip

    @property
    def nbytes(self) -> int:
        return int(self.mean.nbytes + self.scale.nbytes)

    def to_arrays(self, prefix: str = "norm") -> dict[str, np.ndarray]:
        return {f"{prefix}.mean": self.mean, f"{prefix}.scale": self.scale}

    @classmethod
    def from_arrays(cls, arrays: dict[str, np.ndarray], prefix: str = "norm") -> Normalizer:
        return cls(mean=arrays[f"{prefix}.mean"], scale=arrays[f"{prefix}.scale"])

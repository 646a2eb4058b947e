"""The methods the harness compares, built from one small spec each.

- ``gridplace``: :class:`~service.encoding.PhaseEncoder` (pattern-learned columns, ρ and k).
- ``yu``: Yu et al.'s rhythmic encoder (co-prime periods, every column). So that every
  method gets the same (ρ, k) search, ``ρ < 1`` keeps an evenly spaced ``ρ·d`` columns of
  the descriptor (a fixed, unlearned subset; its bit mask is charged to the storage).
- ``exact_nn``: brute-force nearest neighbour on the (ρ-subsampled) normalised descriptors.
- ``pq``: faiss product quantisation (``m`` sub-quantisers of 8 bits), when faiss is installed.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from service.encoding import ExactNN, PhaseEncoder, PQIndex, RhythmicEncoder
from service.encoding.base import Localization
from service.encoding.footprint import Footprint
from service.encoding.patterns import n_selected
from service.errors import InvalidParameterError

METHODS: tuple[str, ...] = ("gridplace", "yu", "exact_nn", "pq")
METHOD_LABELS = {
    "gridplace": "gridplace (phase encoders)",
    "yu": "Yu et al. (rhythmic)",
    "exact_nn": "exact NN",
    "pq": "PQ (faiss)",
}


class Recognizer(Protocol):
    def fit(self, X: Any, y: Any = None) -> Any: ...
    def localize(self, X: Any) -> Localization: ...
    def footprint(self) -> Footprint: ...


def spaced_columns(n_features: int, rho: float) -> np.ndarray:
    """``round(ρ·d)`` evenly spaced column indices, ascending and distinct."""
    k = n_selected(n_features, rho)
    return np.unique(np.round(np.linspace(0, n_features - 1, k)).astype(np.int64))


class ColumnSubset:
    """Fit and query ``inner`` on a fixed subset of the descriptor columns."""

    def __init__(self, inner: Recognizer, rho: float) -> None:
        self.inner = inner
        self.rho = rho

    def fit(self, X: np.ndarray, y: Any = None) -> ColumnSubset:
        del y
        self.n_features_in_ = int(X.shape[1])
        self.columns_ = spaced_columns(self.n_features_in_, self.rho)
        self.inner.fit(np.asarray(X)[:, self.columns_])
        return self

    def localize(self, X: np.ndarray) -> Localization:
        return self.inner.localize(np.asarray(X)[:, self.columns_])

    def footprint(self) -> Footprint:
        fp = Footprint()
        fp.merge(self.inner.footprint())
        if self.columns_.size < self.n_features_in_:
            fp.add("column_mask", self.n_features_in_ / 8.0, -(-self.n_features_in_ // 8))
        return fp


@dataclass(frozen=True)
class MethodSpec:
    """One method at one parameter setting."""

    method: str
    rho: float = 1.0
    k: int | None = None  # number of patterns (gridplace, yu)
    trainer: str = "ridge"
    dtype: str = "float32"
    extra: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.method not in METHODS:
            raise InvalidParameterError(f"unknown method {self.method!r}; choose from {METHODS}")
        if self.method in ("gridplace", "yu") and self.k is None:
            raise InvalidParameterError(f"{self.method} needs k (the number of patterns)")

    def build(self) -> Recognizer:
        if self.method == "gridplace":
            return PhaseEncoder(
                n_patterns=int(self.k or 2), rho=self.rho, trainer=self.trainer,
                dtype=self.dtype, **self.extra,
            )  # fmt: skip
        inner: Recognizer
        if self.method == "yu":
            inner = RhythmicEncoder(
                n_patterns=int(self.k or 2), trainer=self.trainer, dtype=self.dtype, **self.extra
            )
        elif self.method == "exact_nn":
            inner = ExactNN(dtype=self.dtype, **self.extra)
        else:
            inner = PQIndex(**self.extra)
        return inner if self.rho >= 1.0 else ColumnSubset(inner, self.rho)

    def params(self) -> dict[str, Any]:
        """JSON-ready parameters (only those that apply to the method)."""
        out: dict[str, Any] = {"rho": self.rho, "dtype": self.dtype}
        if self.method in ("gridplace", "yu"):
            out.update(k=self.k, trainer=self.trainer)
        if self.method == "pq":
            out.pop("dtype")
        out.update(self.extra)
        return out

    def short(self) -> str:
        bits = [f"ρ={self.rho:g}"]
        if self.k is not None:
            bits.append(f"k={self.k}")
        bits += [f"{k}={v}" for k, v in self.extra.items()]
        return f"{self.method}({', '.join(bits)})"

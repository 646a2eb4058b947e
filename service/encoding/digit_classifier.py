"""One digit's classifier: pattern-learned columns plus a one-vs-rest linear model.

A phase encoder is one of these per period; the chunk classifier is one of these with the
chunk id as its digit.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from service.encoding.decoding import log_probabilities
from service.encoding.patterns import PatternSelection, learn_pattern
from service.encoding.progress import StepFn
from service.encoding.quantization import QuantizedLinear, pack_columns, unpack_columns
from service.encoding.trainers import train_linear


@dataclass
class DigitClassifier:
    columns: np.ndarray  # selected descriptor columns, ascending
    linear: QuantizedLinear  # (n_classes, d') weights and biases
    pattern: PatternSelection | None = None  # kept after fit, not stored in artifacts
    temperature: float = 1.0  # scores are divided by it before the log-softmax

    @classmethod
    def fit(
        cls,
        Xn: np.ndarray,
        labels: np.ndarray,
        n_classes: int,
        *,
        rho: float,
        gamma: float | None,
        **train: Any,
    ) -> DigitClassifier:
        """Pattern learning on all columns of ``Xn``, then the linear model on the kept ones."""
        pattern = learn_pattern(Xn, labels, rho, gamma, n_classes)
        return cls.fit_selected(Xn[:, pattern.columns], labels, n_classes, pattern, **train)

    @classmethod
    def fit_selected(
        cls,
        X_sel: np.ndarray,
        labels: np.ndarray,
        n_classes: int,
        pattern: PatternSelection,
        *,
        trainer: str,
        C: float,
        dtype: str,
        random_state: int | None,
        n_jobs: int = 1,
        progress: StepFn | None = None,
        temperature: float = 1.0,
    ) -> DigitClassifier:
        """Train the linear model on rows already restricted to ``pattern.columns``;
        ``progress(done, total)`` follows its classes."""
        W, b = train_linear(
            X_sel, labels, n_classes, trainer, C=C, random_state=random_state, n_jobs=n_jobs,
            progress=progress,
        )
        return cls(pattern.columns, QuantizedLinear.from_dense(W, b, dtype), pattern,
                   float(temperature))  # fmt: skip

    @property
    def n_classes(self) -> int:
        return int(self.linear.weight.shape[0])

    def log_probs(self, Xn: np.ndarray) -> np.ndarray:
        scores = self.linear.scores(Xn[:, self.columns])
        if self.temperature != 1.0:
            scores = scores * (1.0 / self.temperature)  # as the serving plan scales them
        return log_probabilities(scores)

    @property
    def nbytes(self) -> int:
        """Stored bytes: the weights, and the temperature where it is not 1."""
        return self.linear.nbytes + (8 if self.temperature != 1.0 else 0)

    def paper_bytes(self) -> float:
        """``8(d'+1)`` per class: float64 weights plus bias."""
        return 8.0 * (self.columns.size + 1) * self.n_classes

    def mask_bytes(self, n_features: int) -> int:
        return int(pack_columns(self.columns, n_features).nbytes)

    def to_arrays(self, prefix: str, n_features: int) -> dict[str, np.ndarray]:
        out = self.linear.to_arrays(prefix)
        out[f"{prefix}.mask"] = pack_columns(self.columns, n_features)
        if self.temperature != 1.0:  # absent in older artifacts: 1
            out[f"{prefix}.temperature"] = np.array([self.temperature], dtype=np.float64)
        return out

    @classmethod
    def from_arrays(
        cls, arrays: dict[str, np.ndarray], prefix: str, n_features: int
    ) -> DigitClassifier:
        temperature = arrays.get(f"{prefix}.temperature")
        return cls(
            unpack_columns(arrays[f"{prefix}.mask"], n_features),
            QuantizedLinear.from_arrays(arrays, prefix),
            temperature=1.0 if temperature is None else float(temperature[0]),
        )

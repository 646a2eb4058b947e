"""What every gridplace model shares: the scikit-learn estimator contract, localisation
results with confidence, scoring, and the hooks the artifact store uses."""

from __future__ import annotations

from abc import abstractmethod
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np
from sklearn.base import BaseEstimator

from service.encoding.footprint import Footprint
from service.encoding.validation import check_descriptors
from service.errors import InvalidParameterError, NotFittedError


@dataclass(frozen=True)
class Localization:
    """Answers for a batch of queries (all arrays have one entry per query)."""

    index: np.ndarray  # int64 frame index on the route
    confidence: np.ndarray  # float64 in [0, 1]; threshold it to reject queries
    chunk: np.ndarray  # int64 chunk that answered (0 without chunking)
    log_score: np.ndarray  # float64 log of the confidence (finer ranking near 0)

    def __len__(self) -> int:
        return int(self.index.shape[0])


def precision_at(pred: np.ndarray, truth: np.ndarray, tolerance: int = 0) -> float:
    """Fraction of queries whose prediction lies within ``tolerance`` frames of the truth."""
    pred = np.asarray(pred, dtype=np.int64)
    truth = np.asarray(truth, dtype=np.int64)
    if pred.shape != truth.shape:
        raise InvalidParameterError(
            f"{pred.shape[0]} predictions but {truth.shape[0]} ground-truth indices"
        )
    if pred.size == 0:
        return 0.0
    return float(np.mean(np.abs(pred - truth) <= tolerance))


class PlaceRecognizer(BaseEstimator):  # type: ignore[misc]
    """Base class: ``fit(X)`` with rows in route order, ``predict(Q)`` gives frame indices."""

    #: name written into artifact manifests; registered in ``service.encoding.registry``
    kind: ClassVar[str] = ""

    # -- estimator contract -------------------------------------------------------------
    @abstractmethod
    def fit(self, X: Any, y: Any = None) -> PlaceRecognizer: ...

    @abstractmethod
    def localize(self, X: Any) -> Localization:
        """Frame index, chunk and confidence for every query row."""

    def predict(self, X: Any) -> np.ndarray:
        return self.localize(X).index

    def score(self, X: Any, y: Any = None, tolerance: int = 0) -> float:
        """Precision within ``tolerance`` frames; ``y`` defaults to row i ↔ frame i."""
        Q = self._check_query(X)
        truth = np.arange(Q.shape[0]) if y is None else np.asarray(y)
        return precision_at(self.predict(Q), truth, tolerance)

    def _check_query(self, X: Any) -> np.ndarray:
        self._check_fitted()
        return check_descriptors(X, n_features=self.n_features_in_, what="query descriptors")

    def _check_fitted(self) -> None:
        if not hasattr(self, "n_frames_"):
            raise NotFittedError(f"this {type(self).__name__} is not fitted yet; call fit first")

    def __sklearn_is_fitted__(self) -> bool:
        return hasattr(self, "n_frames_")

    # -- storage ------------------------------------------------------------------------
    @abstractmethod
    def footprint(self) -> Footprint: ...

    @abstractmethod
    def _to_arrays(self) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        """Tensors and JSON metadata that fully describe the fitted model."""

    @classmethod
    @abstractmethod
    def _from_arrays(
        cls, params: dict[str, Any], arrays: dict[str, np.ndarray], meta: dict[str, Any]
    ) -> PlaceRecognizer: ...

    def _set_fitted(self, n_frames: int, n_features: int, n_traversals: int = 1) -> None:
        """``n_frames`` is the number of places; ``n_traversals`` how many traversals of them
        the model was trained on."""
        self.__dict__.pop("_serving_plan", None)  # what serving precomputed is stale
        self.__dict__.pop("_drive_scorer", None)
        self.n_frames_ = int(n_frames)
        self.n_features_in_ = int(n_features)
        self.n_traversals_ = int(n_traversals)

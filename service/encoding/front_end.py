"""What every row goes through before the digit classifiers: column z-scoring with the
route's statistics, then (optionally) the PCA projection of :mod:`service.encoding.projection`.

Training rows and queries take exactly the same path. A chunked route fits one front-end on
the whole route, shared by its chunk classifier and every chunk encoder.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from service.encoding.normalization import Normalizer
from service.encoding.projection import Projection

_BLOCK_ROWS = 8192  # rows transformed at a time when a whole route is projected


@dataclass(frozen=True)
class FrontEnd:
    normalizer: Normalizer | None
    projection: Projection | None = None

    @classmethod
    def fit(
        cls, X: np.ndarray, normalize: bool = True, n_components: int | None = None,
        whiten_power: float = 0.75, dtype: str = "float32",
    ) -> FrontEnd:  # fmt: skip
        """The normaliser of ``X`` (when ``normalize``), then the projection fitted on the
        normalised rows (when ``n_components`` is set)."""
        normalizer = Normalizer.fit(X) if normalize else None
        if n_components is None:
            return cls(normalizer)
        Xn = _Normalised(X, normalizer)
        if dtype == "binary":  # sign bits are for class templates; the projection keeps int8
            dtype = "int8"
        return cls(normalizer, Projection.fit(Xn, int(n_components), whiten_power, dtype))

    @classmethod
    def of_params(cls, X: np.ndarray, params: dict[str, Any]) -> FrontEnd:
        """:meth:`fit` with an estimator's parameters (``normalize``, ``n_components``, …)."""
        return cls.fit(X, bool(params.get("normalize", True)), params.get("n_components"),
                       float(params.get("whiten_power", 0.75)),
                       str(params.get("dtype", "float32")))  # fmt: skip

    @property
    def n_features(self) -> int:
        """Width of the raw rows (0 when neither stage is present)."""
        if self.normalizer is not None:
            return int(self.normalizer.mean.shape[0])
        return 0 if self.projection is None else self.projection.n_features

    @property
    def n_outputs(self) -> int | None:
        """Width of the transformed rows (``None``: the raw width)."""
        return None if self.projection is None else self.projection.n_components

    def transform(self, X: np.ndarray) -> np.ndarray:
        Z = np.asarray(X, np.float64) if self.normalizer is None else self.normalizer.transform(X)
        return Z if self.projection is None else self.projection.transform(Z)

    def transform_blocks(self, X: np.ndarray, block_rows: int = _BLOCK_ROWS) -> np.ndarray:
        """:meth:`transform` of a projected route in row blocks (no full-width float64 copy)."""
        if self.projection is None:
            return self.transform(X)
        out = np.empty((X.shape[0], self.projection.n_components))
        for s in range(0, X.shape[0], block_rows):
            out[s : s + block_rows] = self.transform(X[s : s + block_rows])
        return out

    @property
    def nbytes(self) -> int:
        return sum(p.nbytes for p in (self.normalizer, self.projection) if p is not None)

    def add_to(self, footprint: Any) -> None:
        """Footprint lines: the normalisation (outside the paper's formula) and the projection."""
        if self.normalizer is not None:
            footprint.add("normalization", 0.0, self.normalizer.nbytes)
        if self.projection is not None:
            footprint.add("projection", self.projection.paper_bytes(), self.projection.nbytes)

    def to_arrays(self, prefix: str = "norm") -> dict[str, np.ndarray]:
        out: dict[str, np.ndarray] = {}
        if self.normalizer is not None:
            out.update(self.normalizer.to_arrays(prefix))
        if self.projection is not None:
            out.update(self.projection.to_arrays(f"{prefix}.proj"))
        return out

    @classmethod
    def from_arrays(cls, arrays: dict[str, np.ndarray], prefix: str = "norm") -> FrontEnd | None:
        """The stored front-end, or ``None`` when the model stores neither stage."""
        normalizer = (
            Normalizer.from_arrays(arrays, prefix) if f"{prefix}.mean" in arrays else None
        )
        projection = Projection.from_arrays(arrays, f"{prefix}.proj")
        if normalizer is None and projection is None:
            return None
        return cls(normalizer, projection)


class _Normalised:
    """Rows of ``X`` normalised on access (``Projection.fit`` reads only its sample)."""

    def __init__(self, X: np.ndarray, normalizer: Normalizer | None) -> None:
        self._X, self._normalizer = X, normalizer
        self.shape = X.shape

    def __getitem__(self, rows: Any) -> np.ndarray:
        block = np.asarray(self._X[rows], dtype=np.float64)
        return block if self._normalizer is None else self._normalizer.transform(block)

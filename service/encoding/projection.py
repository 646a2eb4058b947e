"""PCA projection with partial whitening: the condition-robust front-end of an encoder.

Fitted on the (z-scored) training rows: the top ``n_components`` principal axes ``v_c`` with
eigenvalues ``λ_c``, each divided by ``√λ_c^power`` (``power`` 0 = plain PCA, 1 = full
whitening), then every projected row is L2-normalised. Partial whitening lifts the
low-variance components that differ between places above the few high-variance ones that
mostly follow the lighting and the season; the unit norm makes scores cosines.

The map ``z ↦ (z − μ)·P`` is stored as one :class:`QuantizedLinear` (weights ``Pᵀ`` of shape
``(n_components, d)``, bias ``−μ·P``) at the model's storage dtype, and queries go through
exactly the stored (dequantised) values.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from service.encoding.quantization import QuantizedLinear
from service.errors import InvalidParameterError

_RANK_TOL = 1e-10  # eigenvalues below this fraction of the largest are rank deficiency
_MIN_NORM = 1e-12  # a row projecting to ~0 (a constant frame) stays 0, not NaN


def sample_rows(n_rows: int, max_rows: int) -> np.ndarray:
    """At most ``max_rows`` evenly spaced row indices of ``n_rows`` (all when fewer)."""
    if n_rows <= max_rows:
        return np.arange(n_rows)
    return np.unique(np.linspace(0, n_rows - 1, max_rows).round().astype(np.int64))


def _top_eigen(sym: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Eigenvalues (descending) and eigenvectors of a symmetric matrix."""
    evals, evecs = np.linalg.eigh(sym)
    order = np.argsort(evals)[::-1]
    return evals[order], evecs[:, order]


@dataclass(frozen=True)
class Projection:
    linear: QuantizedLinear  # (n_components, d) weights, (n_components,) bias

    @classmethod
    def fit(
        cls, Xn: np.ndarray, n_components: int, power: float = 0.75, dtype: str = "float32",
        max_rows: int = 16384, block_rows: int = 8192,
    ) -> Projection:  # fmt: skip
        """Principal axes of ``Xn`` (rows are frames): of at most ``max_rows`` evenly spaced
        rows (a long route's sample), from the smaller of the ``d×d`` covariance and the
        Gram matrix. ``n_components`` is capped at the rank of those rows."""
        if int(n_components) < 1:
            raise InvalidParameterError(f"n_components must be >= 1, got {n_components}")
        if not 0.0 <= power <= 1.0:
            raise InvalidParameterError(f"whiten_power must lie in [0, 1], got {power}")
        rows = sample_rows(Xn.shape[0], max_rows)
        X = np.asarray(Xn[rows], dtype=np.float64)
        n, d = X.shape
        mean = X.mean(axis=0)
        X -= mean
        if n < d:  # the n×n Gram matrix has the same non-zero spectrum, and is smaller
            evals, u = _top_eigen(X @ X.T / n)
            evecs = X.T @ u / np.sqrt(np.maximum(evals * n, _MIN_NORM))
        else:
            cov = np.zeros((d, d))
            for s in range(0, n, block_rows):
                cov += X[s : s + block_rows].T @ X[s : s + block_rows]
            evals, evecs = _top_eigen(cov / n)
        rank = int(np.sum(evals > _RANK_TOL * max(float(evals[0]), _MIN_NORM)))
        m = max(1, min(int(n_components), rank))
        axes = evecs[:, :m]
        # A deterministic sign: the largest-magnitude entry of every axis is positive.
        flip = np.sign(axes[np.abs(axes).argmax(axis=0), np.arange(m)])
        axes = axes * np.where(flip == 0, 1.0, flip)
        scale = np.maximum(evals[:m], _MIN_NORM) ** (-0.5 * power)
        P = axes * scale  # (d, m)
        return cls(QuantizedLinear.from_dense(P.T.copy(), -(mean @ P), dtype))

    @property
    def n_components(self) -> int:
        return int(self.linear.weight.shape[0])

    @property
    def n_features(self) -> int:
        return int(self.linear.weight.shape[1])

    def transform(self, Xn: np.ndarray) -> np.ndarray:
        """Projected, L2-normalised rows (float64), from the stored weights."""
        Z = self.linear.scores(np.asarray(Xn, dtype=np.float64))
        norm = np.sqrt(np.einsum("ij,ij->i", Z, Z))[:, None]
        return Z / np.maximum(norm, _MIN_NORM)

    @property
    def nbytes(self) -> int:
        return self.linear.nbytes

    def paper_bytes(self) -> float:
        """Float64 matrix and bias, as the paper's formula counts weights."""
        return 8.0 * (self.n_features + 1) * self.n_components

    def to_arrays(self, prefix: str) -> dict[str, np.ndarray]:
        return self.linear.to_arrays(prefix)

    @classmethod
    def from_arrays(cls, arrays: dict[str, np.ndarray], prefix: str) -> Projection | None:
        if f"{prefix}.weight" not in arrays:
            return None
        return cls(QuantizedLinear.from_arrays(arrays, prefix))

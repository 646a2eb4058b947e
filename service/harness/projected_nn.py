"""Exact nearest neighbour in the projected space of gridplace's front-end: the baseline that
says how much of an encoder's precision comes from the projection alone.

The rows go through :class:`service.encoding.front_end.FrontEnd` exactly as a ``robust``
encoder's do (column z-scoring, PCA to ``n_components`` whitened with ``whiten_power``, L2
normalisation); every projected training row is stored (float32) and a query's answer is the
nearest one. Storage: ``N·n_components·4`` bytes plus the front-end, linear in ``N``.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from service.encoding.base import Localization
from service.encoding.footprint import Footprint
from service.encoding.front_end import FrontEnd

_BLOCK = 1024  # query rows scored against every frame at a time


class ProjectedNN:
    kind = "projected_nn"

    def __init__(self, n_components: int = 128, whiten_power: float = 0.75,
                 dtype: str = "float32", exclusion: int = 10) -> None:  # fmt: skip
        self.n_components = n_components
        self.whiten_power = whiten_power
        self.dtype = dtype
        self.exclusion = exclusion

    def fit(self, X: Any) -> ProjectedNN:
        X = np.asarray(X, dtype=np.float64)
        self.front_ = FrontEnd.fit(X, True, self.n_components, self.whiten_power, self.dtype)
        self.reference_ = self.front_.transform_blocks(X).astype(np.float32)
        self._ref_sq = np.einsum("ij,ij->i", self.reference_, self.reference_)
        step = np.diff(self.reference_.astype(np.float64), axis=0)
        median = float(np.median(np.einsum("ij,ij->i", step, step))) if step.size else 0.0
        self.sigma2_ = median if median > 0 else 1.0
        self.n_frames_, self.n_features_in_ = int(X.shape[0]), int(X.shape[1])
        return self

    def _sq_distances(self, X: Any) -> np.ndarray:
        q = self.front_.transform(np.asarray(X, dtype=np.float64)).astype(np.float32)
        R = self.reference_
        out = self._ref_sq[None, :] - 2.0 * (q @ R.T) + np.einsum("ij,ij->i", q, q)[:, None]
        return np.maximum(out, 0.0)

    def frame_log_scores(self, X: Any) -> np.ndarray:
        """Gaussian log-likelihood ``−d²/(2σ²)`` of every frame (as :class:`ExactNN`)."""
        X = np.asarray(X)
        out = np.empty((X.shape[0], self.n_frames_))
        for s in range(0, X.shape[0], _BLOCK):
            out[s : s + _BLOCK] = self._sq_distances(X[s : s + _BLOCK]) * (-0.5 / self.sigma2_)
        return out

    def localize(self, X: Any) -> Localization:
        X = np.asarray(X)
        index = np.empty(X.shape[0], dtype=np.int64)
        conf = np.empty(X.shape[0])
        frames = np.arange(self.n_frames_)
        for s in range(0, X.shape[0], _BLOCK):
            dist = self._sq_distances(X[s : s + _BLOCK])
            best = dist.argmin(axis=1)
            d1 = np.sqrt(dist[np.arange(dist.shape[0]), best])
            far = np.abs(frames[None, :] - best[:, None]) > self.exclusion
            d2 = np.sqrt(np.where(far, dist, np.inf).min(axis=1))
            index[s : s + _BLOCK] = best
            ok = np.isfinite(d2) & (d2 > 0)
            conf[s : s + _BLOCK] = np.where(ok, 1.0 - d1 / np.where(ok, d2, 1.0), 0.0)
        conf = np.clip(conf, 0.0, 1.0)
        return Localization(index, conf, np.zeros_like(index), np.log(np.maximum(conf, 1e-300)))

    def footprint(self) -> Footprint:
        fp = Footprint()
        fp.add("reference", 8.0 * self.reference_.size, int(self.reference_.nbytes))
        self.front_.add_to(fp)
        return fp

"""Baselines in the same API: Yu et al.'s rhythmic encoder and exact nearest neighbour."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from service.encoding.base import Localization, PlaceRecognizer
from service.encoding.digit_classifier import DigitClassifier
from service.encoding.footprint import Footprint
from service.encoding.normalization import Normalizer
from service.encoding.quantization import QuantizedLinear, check_dtype
from service.encoding.trainers import train_linear
from service.encoding.validation import check_descriptors
from service.errors import InvalidParameterError

_BLOCK = 1024  # query rows per block when scoring against every frame


def coprime_periods(n_frames: int, n_patterns: int) -> tuple[int, ...]:
    """Pairwise co-prime periods near ``N^(1/k)`` with product ``≥ N`` (smallest sum found)."""
    if n_frames < 2 or n_patterns < 1:
        raise InvalidParameterError("need n_frames >= 2 and n_patterns >= 1")
    best: tuple[int, ...] | None = None
    start = max(2, int(n_frames ** (1.0 / n_patterns)) - n_patterns)
    for base in range(start, start + 4 * n_patterns + 4):
        picked: list[int] = []
        c = base
        while len(picked) < n_patterns:
            if all(math.gcd(c, p) == 1 for p in picked):
                picked.append(c)
            c += 1
        if math.prod(picked) >= n_frames and (best is None or sum(picked) < sum(best)):
            best = tuple(sorted(picked, reverse=True))
    assert best is not None
    return best


def crt(residues: np.ndarray, periods: Sequence[int]) -> np.ndarray:
    """Chinese-remainder solution ``i mod ∏τ`` of ``i ≡ r_j (mod τ_j)``, per row."""
    M = math.prod(periods)
    out = np.zeros(residues.shape[0], dtype=np.int64)
    for j, p in enumerate(periods):
        Mj = M // p
        out = (out + residues[:, j].astype(np.int64) * Mj * pow(Mj, -1, p)) % M
    return out


class RhythmicEncoder(PlaceRecognizer):
    """Yu et al. (2018): labels ``i mod τ_j`` with pairwise co-prime periods, every column,
    Chinese-remainder decoding; an index ``≥ N`` falls back to the best valid index by
    summed log-probability."""

    kind = "rhythmic_encoder"

    def __init__(
        self,
        n_patterns: int = 2,
        periods: Sequence[int] | None = None,
        trainer: str = "logreg",
        C: float = 4.0,
        dtype: str = "float32",
        random_state: int | None = 0,
    ) -> None:
        self.n_patterns = n_patterns
        self.periods = periods
        self.trainer = trainer
        self.C = C
        self.dtype = dtype
        self.random_state = random_state

    def fit(self, X: Any, y: Any = None) -> RhythmicEncoder:
        del y
        X = check_descriptors(X, min_rows=2, what="training descriptors")
        check_dtype(self.dtype)
        n, d = X.shape
        if self.periods is not None:
            periods = tuple(int(p) for p in self.periods)
            if any(p < 2 for p in periods) or math.prod(periods) < n:
                raise InvalidParameterError(f"periods {periods} must be >= 2 with product >= {n}")
            for a in range(len(periods)):
                for b in range(a + 1, len(periods)):
                    if math.gcd(periods[a], periods[b]) != 1:
                        raise InvalidParameterError(f"periods {periods} are not pairwise co-prime")
        else:
            periods = coprime_periods(n, int(self.n_patterns))
        self.periods_ = periods
        self.normalizer_ = Normalizer.fit(X)
        Xn = self.normalizer_.transform(X)
        cols = np.arange(d)
        self.digits_ = []
        for tau in periods:
            W, bias = train_linear(Xn, np.arange(n) % tau, tau, self.trainer, self.C, self.random_state)
            self.digits_.append(DigitClassifier(cols, QuantizedLinear.from_dense(W, bias, self.dtype)))
        self._set_fitted(n, d)
        return self

    def localize(self, X: Any) -> Localization:
        Qn = self.normalizer_.transform(self._check_query(X))
        logps = [dc.log_probs(Qn) for dc in self.digits_]
        residues = np.stack([lp.argmax(axis=1) for lp in logps], axis=1)
        index = crt(residues, self.periods_)
        rows = np.arange(Qn.shape[0])
        score = np.sum(np.stack([lp[rows, residues[:, j]] for j, lp in enumerate(logps)]), axis=0)
        bad = np.flatnonzero(index >= self.n_frames_)
        if bad.size:
            for s in range(0, bad.size, _BLOCK):
                blk = bad[s : s + _BLOCK]
                total = self._frame_scores([lp[blk] for lp in logps])
                index[blk] = total.argmax(axis=1)
                score[blk] = total.max(axis=1)
        return Localization(index, np.exp(score), np.zeros_like(index), np.asarray(score))

    def _frame_scores(self, logps: list[np.ndarray]) -> np.ndarray:
        frames = np.arange(self.n_frames_)
        total = np.zeros((logps[0].shape[0], self.n_frames_))
        for lp, p in zip(logps, self.periods_, strict=True):
            total += lp[:, frames % p]
        return total

    def frame_log_scores(self, X: Any) -> np.ndarray:
        """Summed log-probability of every frame's residues, ``(n_q, N)``."""
        Qn = self.normalizer_.transform(self._check_query(X))
        return self._frame_scores([dc.log_probs(Qn) for dc in self.digits_])

    def footprint(self) -> Footprint:
        self._check_fitted()
        fp = Footprint()
        for dc in self.digits_:
            fp.add("encoders", dc.paper_bytes(), dc.linear.nbytes)
        fp.add("normalization", 0.0, self.normalizer_.nbytes)
        return fp

    def _to_arrays(self) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        arrays: dict[str, np.ndarray] = self.normalizer_.to_arrays("norm")
        for j, dc in enumerate(self.digits_):
            arrays.update(dc.linear.to_arrays(f"enc.{j}"))
        meta = {"n_frames": self.n_frames_, "n_features": self.n_features_in_,
                "periods": list(self.periods_)}  # fmt: skip
        return arrays, meta

    @classmethod
    def _from_arrays(
        cls, params: dict[str, Any], arrays: dict[str, np.ndarray], meta: dict[str, Any]
    ) -> RhythmicEncoder:
        model = cls(**params)
        d = int(meta["n_features"])
        model.periods_ = tuple(int(p) for p in meta["periods"])
        model.normalizer_ = Normalizer.from_arrays(arrays, "norm")
        model.digits_ = [
            DigitClassifier(np.arange(d), QuantizedLinear.from_arrays(arrays, f"enc.{j}"))
            for j in range(len(model.periods_))
        ]
        model._set_fitted(int(meta["n_frames"]), d)
        return model


class ExactNN(PlaceRecognizer):
    """Stores every (normalised) reference descriptor; brute-force nearest neighbour.

    The storage-linear reference point. ``confidence`` is ``1 − d₁/d₂`` with ``d₂`` the
    nearest distance outside ``±exclusion`` frames of the best match (a ratio test).
    """

    kind = "exact_nn"

    def __init__(self, metric: str = "euclidean", dtype: str = "float32", exclusion: int = 10):
        self.metric = metric
        self.dtype = dtype
        self.exclusion = exclusion

    def fit(self, X: Any, y: Any = None) -> ExactNN:
        del y
        if self.metric not in ("euclidean", "cosine"):
            raise InvalidParameterError(f"metric must be 'euclidean' or 'cosine', got {self.metric!r}")
        if self.dtype not in ("float64", "float32", "float16"):
            raise InvalidParameterError(f"ExactNN stores float64/float32/float16, not {self.dtype!r}")
        X = check_descriptors(X, min_rows=2, what="training descriptors")
        self.normalizer_ = Normalizer.fit(X)
        self.reference_ = self._prepare(self.normalizer_.transform(X)).astype(self.dtype)
        self._cache_search_arrays()
        self._set_fitted(*X.shape)
        return self

    def _cache_search_arrays(self) -> None:
        """float32 reference and its squared norms, computed once (not per query), and the
        scale of the frame scores: ``σ²`` = median squared distance between consecutive
        reference frames (how far one place's descriptor moves within a frame)."""
        self._ref32 = np.ascontiguousarray(self.reference_, dtype=np.float32)
        self._ref_sq = np.einsum("ij,ij->i", self._ref32, self._ref32)
        step = np.diff(self._ref32.astype(np.float64), axis=0)
        median = float(np.median(np.einsum("ij,ij->i", step, step))) if step.size else 0.0
        self.sigma2_ = median if median > 0 else 1.0

    def _sq_distances(self, q: np.ndarray) -> np.ndarray:
        """Squared distances ``(n_q, N)`` of prepared float32 queries to every frame."""
        R, r2 = self._ref32, self._ref_sq
        return np.maximum(r2[None, :] - 2.0 * (q @ R.T) + np.einsum("ij,ij->i", q, q)[:, None], 0)

    def _prepare(self, Xn: np.ndarray) -> np.ndarray:
        if self.metric == "cosine":
            return Xn / np.maximum(np.linalg.norm(Xn, axis=1, keepdims=True), 1e-12)
        return Xn

    def localize(self, X: Any) -> Localization:
        Qn = self._prepare(self.normalizer_.transform(self._check_query(X))).astype(np.float32)
        index = np.empty(Qn.shape[0], dtype=np.int64)
        conf = np.empty(Qn.shape[0])
        frames = np.arange(self.n_frames_)
        for s in range(0, Qn.shape[0], _BLOCK):
            q = Qn[s : s + _BLOCK]
            dist = self._sq_distances(q)
            best = dist.argmin(axis=1)
            d1 = np.sqrt(dist[np.arange(q.shape[0]), best])
            far = np.abs(frames[None, :] - best[:, None]) > self.exclusion
            d2 = np.sqrt(np.where(far, dist, np.inf).min(axis=1))
            index[s : s + _BLOCK] = best
            conf[s : s + _BLOCK] = np.where(np.isfinite(d2) & (d2 > 0), 1.0 - d1 / np.maximum(d2, 1e-12), 0.0)
        conf = np.clip(conf, 0.0, 1.0)
        return Localization(index, conf, np.zeros_like(index), np.log(np.maximum(conf, 1e-300)))

    def frame_log_scores(self, X: Any) -> np.ndarray:
        """Gaussian log-likelihood ``−d²/(2σ²)`` of every frame, ``(n_q, N)`` (``σ²``: see
        :meth:`_cache_search_arrays`)."""
        Qn = self._prepare(self.normalizer_.transform(self._check_query(X))).astype(np.float32)
        out = np.empty((Qn.shape[0], self.n_frames_))
        for s in range(0, Qn.shape[0], _BLOCK):
            out[s : s + _BLOCK] = self._sq_distances(Qn[s : s + _BLOCK]) * (-0.5 / self.sigma2_)
        return out

    def footprint(self) -> Footprint:
        self._check_fitted()
        fp = Footprint()
        fp.add("reference", 8.0 * self.reference_.size, int(self.reference_.nbytes))
        fp.add("normalization", 0.0, self.normalizer_.nbytes)
        return fp

    def _to_arrays(self) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        arrays = {"reference": self.reference_, **self.normalizer_.to_arrays("norm")}
        return arrays, {"n_frames": self.n_frames_, "n_features": self.n_features_in_}

    @classmethod
    def _from_arrays(
        cls, params: dict[str, Any], arrays: dict[str, np.ndarray], meta: dict[str, Any]
    ) -> ExactNN:
        model = cls(**params)
        model.reference_ = arrays["reference"]
        model.normalizer_ = Normalizer.from_arrays(arrays, "norm")
        model._cache_search_arrays()
        model._set_fitted(int(meta["n_frames"]), int(meta["n_features"]))
        return model

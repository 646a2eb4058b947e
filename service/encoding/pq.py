"""Product-quantised nearest neighbour (faiss ``IndexPQ``): the compressed-retrieval baseline.

Optional: needs ``faiss-cpu`` (``pip install 'gridplace[faiss]'``). Storage is ``N·m`` bytes of
codes (8-bit sub-quantisers) plus the codebooks, still linear in ``N``; the index is stored as
faiss's own serialised bytes (a uint8 tensor), never pickle.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from service.encoding.base import Localization, PlaceRecognizer
from service.encoding.footprint import Footprint
from service.encoding.normalization import Normalizer
from service.encoding.validation import check_descriptors
from service.errors import InvalidParameterError

_BLOCK = 256  # query rows per faiss search when scoring every frame, at most
_SEARCH_BUDGET = 1 << 21  # … and at most this many (distance, label) pairs per search
_SIGMA_FRAMES = 4096  # decoded frames used for the frame-score scale


def _faiss() -> Any:
    try:
        import faiss
    except ImportError as exc:
        raise InvalidParameterError(
            "the PQ baseline needs faiss: pip install 'gridplace[faiss]'"
        ) from exc
    return faiss


def faiss_available() -> bool:
    try:
        _faiss()
    except InvalidParameterError:
        return False
    return True


class PQIndex(PlaceRecognizer):
    """Nearest neighbour over product-quantised (normalised) descriptors.

    ``n_subquantizers`` (m) must divide d; each frame costs m bytes. ``confidence`` is
    ``1 − d₁/d₂`` against the nearest match more than ``exclusion`` frames away.
    """

    kind = "pq_index"

    def __init__(self, n_subquantizers: int = 64, exclusion: int = 10, n_candidates: int = 32) -> None:
        self.n_subquantizers = n_subquantizers
        self.exclusion = exclusion
        self.n_candidates = n_candidates

    def fit(self, X: Any, y: Any = None) -> PQIndex:
        del y
        faiss = _faiss()
        X = check_descriptors(X, min_rows=2, what="training descriptors")
        m = int(self.n_subquantizers)
        if m < 1 or X.shape[1] % m:
            raise InvalidParameterError(
                f"n_subquantizers={m} must divide the descriptor size {X.shape[1]}"
            )
        if X.shape[0] < 256:
            raise InvalidParameterError("PQ with 8-bit codebooks needs at least 256 frames")
        self.normalizer_ = Normalizer.fit(X)
        Xn = np.ascontiguousarray(self.normalizer_.transform(X), dtype=np.float32)
        index = faiss.IndexPQ(X.shape[1], m, 8)
        index.train(Xn)
        index.add(Xn)
        self.index_ = index
        self.index_bytes_ = faiss.serialize_index(index)
        self._set_fitted(*X.shape)
        return self

    def localize(self, X: Any) -> Localization:
        Q = self._check_query(X)
        Qn = np.ascontiguousarray(self.normalizer_.transform(Q), dtype=np.float32)
        k = min(self.n_frames_, max(2, int(self.n_candidates)))
        dist, idx = self.index_.search(Qn, k)
        best = idx[:, 0].astype(np.int64)
        far = np.abs(idx - best[:, None]) > self.exclusion
        d1 = np.sqrt(np.maximum(dist[:, 0], 0))
        d2 = np.sqrt(np.maximum(np.where(far, dist, np.inf).min(axis=1), 0))
        with np.errstate(divide="ignore", invalid="ignore"):
            conf = np.where(np.isfinite(d2) & (d2 > 0), 1.0 - d1 / d2, 0.0)
        conf = np.clip(conf.astype(np.float64), 0.0, 1.0)
        return Localization(best, conf, np.zeros_like(best), np.log(np.maximum(conf, 1e-300)))

    def frame_log_scores(self, X: Any) -> np.ndarray:
        """Gaussian log-likelihood ``−d²/(2σ²)`` of every frame from the quantised (ADC)
        distances, ``(n_q, N)``; ``σ²`` is the median squared distance between consecutive
        decoded frames (from the first ``_SIGMA_FRAMES`` frames)."""
        Qn = np.ascontiguousarray(self.normalizer_.transform(self._check_query(X)), dtype=np.float32)
        if getattr(self, "sigma2_", None) is None:
            n = min(self.n_frames_, _SIGMA_FRAMES)
            step = np.diff(self.index_.reconstruct_n(0, n).astype(np.float64), axis=0)
            median = float(np.median(np.einsum("ij,ij->i", step, step)))
            self.sigma2_ = median if median > 0 else 1.0
        out = np.empty((Qn.shape[0], self.n_frames_))
        block = max(1, min(_BLOCK, _SEARCH_BUDGET // self.n_frames_))  # faiss answers k = N
        rows = np.arange(min(block, Qn.shape[0]))[:, None]
        for s in range(0, Qn.shape[0], block):
            q = Qn[s : s + block]
            dist, idx = self.index_.search(q, self.n_frames_)
            out[s : s + q.shape[0]][rows[: q.shape[0]], idx] = np.maximum(dist, 0) * (-0.5 / self.sigma2_)
        return out

    def footprint(self) -> Footprint:
        self._check_fitted()
        fp = Footprint()
        codes = self.n_frames_ * int(self.n_subquantizers)
        books = 256 * self.n_features_in_ * 4
        fp.add("pq_codes", codes, codes)
        fp.add("pq_codebooks", books, books)
        fp.add("normalization", 0.0, self.normalizer_.nbytes)
        return fp

    def _to_arrays(self) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        arrays = {"pq.index": np.asarray(self.index_bytes_, dtype=np.uint8),
                  **self.normalizer_.to_arrays("norm")}  # fmt: skip
        return arrays, {"n_frames": self.n_frames_, "n_features": self.n_features_in_}

    @classmethod
    def _from_arrays(
        cls, params: dict[str, Any], arrays: dict[str, np.ndarray], meta: dict[str, Any]
    ) -> PQIndex:
        faiss = _faiss()
        model = cls(**params)
        model.index_bytes_ = np.asarray(arrays["pq.index"], dtype=np.uint8)
        model.index_ = faiss.deserialize_index(model.index_bytes_)
        model.normalizer_ = Normalizer.from_arrays(arrays, "norm")
        model._set_fitted(int(meta["n_frames"]), int(meta["n_features"]))
        return model

"""Long routes: C contiguous chunks, one phase encoder each, and a chunk classifier.

A query goes chunk classifier → its ``top_chunks`` most likely chunks → each chunk's encoder
→ the candidate with the best joint log-probability (chunk and digits together) → global
index. Chunks are ranges of places; they train independently (in parallel processes with
``n_jobs``), each on the rows of its own places only (of every traversal,
:mod:`service.encoding.traversals`); the building blocks (:mod:`service.encoding.chunk_training`)
are public so a distributed queue can run one chunk per job and
:meth:`ChunkedPlaceEncoder.assemble` the result.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from joblib import Parallel, delayed

from service.encoding import chunked_appending
from service.encoding.appending import ClassTally
from service.encoding.base import Localization, PlaceRecognizer
from service.encoding.chunk_training import (
    ENCODER_PARAMS,
    FRONT_PARAMS,
    as_front_end,
    chunk_encoder,
    fit_chunk_classifier,
    fit_chunk_encoder,
    fit_front_end,
    plan_chunks,
)
from service.encoding.conditions import conditions_from_arrays, conditions_to_arrays
from service.encoding.digit_classifier import DigitClassifier
from service.encoding.encoder import PhaseEncoder
from service.encoding.footprint import Footprint
from service.encoding.front_end import FrontEnd
from service.encoding.normalization import Normalizer
from service.encoding.progress import ProgressFn, Steps
from service.encoding.serving_plan import plan_for
from service.encoding.traversals import as_traversals, chunk_rows
from service.errors import InvalidParameterError

class ChunkedPlaceEncoder(PlaceRecognizer):
    """Phase encoders per chunk plus a chunk classifier (all :class:`PhaseEncoder` params,
    and ``n_chunks``, ``chunk_rho`` (``None`` = ``rho``), ``top_chunks``, ``n_jobs``)."""

    kind = "chunked_encoder"

    def __init__(
        self,
        n_chunks: int = 4,
        n_patterns: int = 2,
        periods: Sequence[int] | None = None,
        rho: float = 0.5,
        chunk_rho: float | None = None,
        gamma: float | None = None,
        trainer: str = "logreg",
        C: float = 4.0,
        decode: str = "joint",
        beam_width: int = 64,
        top_chunks: int = 2,
        dtype: str = "float32",
        n_jobs: int = 1,
        random_state: int | None = 0,
        code: str = "mixed_radix",
        code_ratio: float = 1.0,
        code_exponent: float = 1.0,
        n_components: int | None = None,
        whiten_power: float = 0.75,
        temperature: float | None = None,
        auto_width: bool = False,
    ) -> None:
        self.n_chunks = n_chunks
        self.n_patterns = n_patterns
        self.periods = periods
        self.rho = rho
        self.chunk_rho = chunk_rho
        self.gamma = gamma
        self.trainer = trainer
        self.C = C
        self.decode = decode
        self.beam_width = beam_width
        self.top_chunks = top_chunks
        self.dtype = dtype
        self.n_jobs = n_jobs
        self.random_state = random_state
        self.code = code
        self.code_ratio = code_ratio
        self.code_exponent = code_exponent
        self.n_components = n_components
        self.whiten_power = whiten_power
        self.temperature = temperature
        self.auto_width = auto_width

    def fit(
        self, X: Any, y: Any = None, progress: ProgressFn | None = None, *, places: Any = None
    ) -> ChunkedPlaceEncoder:
        """Fit on one traversal (rows in route order) or several, frame-aligned or with
        ``places`` (:mod:`service.encoding.traversals`); chunks are ranges of places."""
        del y
        tr = as_traversals(X, places, keep_dtype=True)
        X, idx = tr.rows, tr.places
        if int(self.top_chunks) < 1:
            raise InvalidParameterError(f"top_chunks must be >= 1, got {self.top_chunks}")
        PhaseEncoder(
            **{k: getattr(self, k) for k in (*ENCODER_PARAMS, *FRONT_PARAMS)}
        )._validate_params(X.shape[1])
        bounds = plan_chunks(tr.n_places, int(self.n_chunks))
        params = self.get_params()
        normalizer = fit_front_end(X, params, bounds)
        steps = self._steps(progress, bounds, params)
        classifier, tally = fit_chunk_classifier(X, bounds, normalizer, params, steps.scope(0), idx)
        steps.done(0)
        rows = None if idx is None else chunk_rows(idx, bounds)
        # Chunks fitted in this process report per class; in child processes, per chunk.
        inline = int(self.n_jobs) == 1
        jobs = (
            delayed(fit_chunk_encoder)(
                X[s:e] if rows is None else X[rows[c]], normalizer, params,
                steps.scope(c + 1) if inline else None,
                None if rows is None or idx is None else idx[rows[c]] - s,
            )
            for c, (s, e) in enumerate(zip(bounds[:-1], bounds[1:], strict=True))
        )  # fmt: skip
        encoders: list[PhaseEncoder] = []
        runner = Parallel(n_jobs=int(self.n_jobs), return_as="generator")
        for enc in runner(jobs):
            encoders.append(enc)
            steps.done(len(encoders))
        return self._assemble(normalizer, bounds, classifier, encoders, tr.n_traversals, tally)

    def partial_fit(
        self, X: Any, y: Any = None, *, places: Any = None, extend: bool = False,
        whiten: bool | None = None, condition: str | None = None,
    ) -> ChunkedPlaceEncoder:  # fmt: skip
        """Append traversals as :meth:`PhaseEncoder.partial_fit` does, to the chunk
        classifier and each chunk's encoder (:mod:`service.encoding.chunked_appending`: no
        extension, no whitening)."""
        del y
        self._check_fitted()
        chunked_appending.append(self, X, places, extend, whiten, condition)
        return self

    @staticmethod
    def _steps(progress: ProgressFn | None, bounds: np.ndarray, params: dict[str, Any]) -> Steps:
        """The chunk classifier (one unit per chunk), then every chunk (its Στ)."""
        n_chunks = len(bounds) - 1
        encoder = chunk_encoder(params)
        budgets = [n_chunks] + [sum(encoder.periods_for(int(n))) for n in np.diff(bounds)]
        labels = ["chunk classifier"] + [f"chunk {c + 1}/{n_chunks}" for c in range(n_chunks)]
        return Steps(progress, labels, budgets)

    @classmethod
    def assemble(
        cls,
        params: dict[str, Any],
        normalizer: FrontEnd | Normalizer,
        bounds: np.ndarray,
        classifier: DigitClassifier,
        encoders: Sequence[PhaseEncoder],
        n_traversals: int = 1,
        tally: ClassTally | None = None,
    ) -> ChunkedPlaceEncoder:
        """Build a fitted model from parts trained elsewhere (e.g. one queue job per chunk);
        ``tally``: the chunk classifier's counts, for appending."""
        return cls(**params)._assemble(normalizer, bounds, classifier, encoders, n_traversals, tally)

    def _assemble(
        self,
        normalizer: FrontEnd | Normalizer,
        bounds: np.ndarray,
        classifier: DigitClassifier,
        encoders: Sequence[PhaseEncoder],
        n_traversals: int = 1,
        tally: ClassTally | None = None,
    ) -> ChunkedPlaceEncoder:
        bounds = np.asarray(bounds, dtype=np.int64)
        if len(encoders) != len(bounds) - 1 or classifier.n_classes != len(encoders):
            raise InvalidParameterError("chunk encoders, bounds and classifier disagree")
        for enc, size in zip(encoders, np.diff(bounds), strict=True):
            if enc.n_frames_ != size:
                raise InvalidParameterError("a chunk encoder was trained on another chunk size")
        self.normalizer_ = as_front_end(normalizer)
        self.chunk_bounds_ = bounds
        self.chunk_classifier_ = classifier
        self.chunk_encoders_ = list(encoders)
        self.chunk_tally_ = tally if tally is not None and tally.counts.shape[0] == len(encoders) else None
        self.conditions_: dict[str, Any] = {}
        self._set_fitted(int(bounds[-1]), self.normalizer_.n_features, n_traversals)
        return self

    # -- querying -----------------------------------------------------------------------
    def localize(self, X: Any) -> Localization:
        """Chunk classifier → ``top_chunks`` chunks → exact joint decode of chunk and digits,
        all queries at once (:mod:`service.encoding.serving_plan`)."""
        Q = self._check_query(X)
        return plan_for(self).localize(Q)

    def frame_log_scores(self, X: Any) -> np.ndarray:
        """Log-probability of every frame, ``(n_q, N)``: chunk log-probability plus the chunk
        encoder's frame scores, for the ``top_chunks`` chunks of each query (−inf elsewhere)."""
        Q = self._check_query(X)
        return plan_for(self).frame_log_scores(Q)

    # -- storage ------------------------------------------------------------------------
    def footprint(self) -> Footprint:
        self._check_fitted()
        fp = Footprint()
        for enc in self.chunk_encoders_:
            fp.merge(enc.footprint())
        clf = self.chunk_classifier_
        width = self._digit_width()
        fp.add("chunk_classifier", clf.paper_bytes(), clf.nbytes)
        fp.add("chunk_classifier_mask", width / 8.0, clf.mask_bytes(width))
        self.normalizer_.add_to(fp)
        return fp

    def _digit_width(self) -> int:
        out = self.normalizer_.n_outputs
        return self.n_features_in_ if out is None else int(out)

    def _to_arrays(self) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        self._check_fitted()
        arrays = self.chunk_classifier_.to_arrays("chunk_clf", self._digit_width())
        arrays.update(self.normalizer_.to_arrays("norm"))
        chunks = []
        for c, enc in enumerate(self.chunk_encoders_):
            enc_arrays, enc_meta = enc._to_arrays(prefix=f"chunk.{c}.")
            arrays.update(enc_arrays)
            chunks.append(enc_meta)
        meta = {
            "n_frames": self.n_frames_,
            "n_features": self.n_features_in_,
            "chunk_bounds": self.chunk_bounds_.tolist(),
            "chunks": chunks,
            "n_traversals": self.n_traversals_,
        }
        if keys := conditions_to_arrays(self.conditions_, arrays):
            meta["conditions"] = keys
        return arrays, meta

    def _state_arrays(self) -> dict[str, np.ndarray]:
        return chunked_appending.state_arrays(self)

    @classmethod
    def _from_arrays(
        cls, params: dict[str, Any], arrays: dict[str, np.ndarray], meta: dict[str, Any]
    ) -> ChunkedPlaceEncoder:
        enc_params = {k: params[k] for k in ENCODER_PARAMS if k in params}
        encoders = [
            PhaseEncoder._from_arrays({**enc_params, "normalize": False}, arrays, m, f"chunk.{c}.")
            for c, m in enumerate(meta["chunks"])
        ]
        front = FrontEnd.from_arrays(arrays, "norm")
        if front is None or front.normalizer is None:
            raise ValueError("a chunked model stores its normaliser")
        width = front.n_outputs or int(meta["n_features"])
        model = cls.assemble(
            params,
            front,
            np.asarray(meta["chunk_bounds"], dtype=np.int64),
            DigitClassifier.from_arrays(arrays, "chunk_clf", width),
            encoders,
            int(meta.get("n_traversals", 1)),
            ClassTally.from_arrays(arrays, chunked_appending.TALLY_PREFIX),
        )
        model.conditions_ = conditions_from_arrays(arrays, meta.get("conditions"))
        return model

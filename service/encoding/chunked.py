"""Long routes: C contiguous chunks, one phase encoder each, and a chunk classifier.

A query goes chunk classifier → its ``top_chunks`` most likely chunks → each chunk's encoder
→ the candidate with the best joint log-probability (chunk and digits together) → global
index. Chunks are ranges of places; they train independently (in parallel processes with
``n_jobs``), each on the rows of its own places only (of every traversal,
:mod:`service.encoding.traversals`); the building blocks are public so a distributed queue
can run one chunk per job and :meth:`ChunkedPlaceEncoder.assemble` the result.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from joblib import Parallel, delayed

from service.encoding import chunked_appending
from service.encoding.appending import ClassTally
from service.encoding.base import Localization, PlaceRecognizer
from service.encoding.chunked_appending import classifier_tally
from service.encoding.conditions import conditions_from_arrays, conditions_to_arrays
from service.encoding.digit_classifier import DigitClassifier
from service.encoding.encoder import PhaseEncoder
from service.encoding.footprint import Footprint
from service.encoding.front_end import FrontEnd
from service.encoding.normalization import Normalizer
from service.encoding.patterns import select_columns
from service.encoding.progress import ProgressFn, Steps
from service.encoding.serving_plan import plan_for
from service.encoding.projection_width import choose_width
from service.encoding.traversals import (
    as_traversals,
    check_rows,
    chunk_of,
    chunk_rows,
    group_means,
    per_place_C,
)
from service.errors import InvalidParameterError

_ENCODER_PARAMS = (
    "n_patterns", "periods", "rho", "gamma", "trainer", "C", "decode", "beam_width", "dtype",
    "random_state", "code", "code_ratio", "code_exponent", "temperature",
)  # fmt: skip
_FRONT_PARAMS = ("n_components", "whiten_power", "auto_width")  # the route's, not each chunk's


_BLOCK_ROWS = 65536  # rows converted to float64 at a time when a whole route is scanned


def check_route(X: Any) -> np.ndarray:
    """Validate training descriptors without converting them: a float array (or a read-only
    memory map of a large route) is checked for shape and finiteness in row blocks and
    returned as it is; anything else goes through :func:`check_descriptors` (float64)."""
    return check_rows(X, keep_dtype=True)


def plan_chunks(n_frames: int, n_chunks: int) -> np.ndarray:
    """Chunk boundaries ``[0, e_1, …, N]`` of ``n_chunks`` near-equal contiguous chunks."""
    if n_chunks < 1:
        raise InvalidParameterError(f"n_chunks must be >= 1, got {n_chunks}")
    if n_frames < 2 * n_chunks:
        raise InvalidParameterError(
            f"{n_frames} frames are too few for {n_chunks} chunks: every chunk needs >= 2 frames",
            n_frames=n_frames,
            n_chunks=n_chunks,
        )
    sizes = np.full(n_chunks, n_frames // n_chunks, dtype=np.int64)
    sizes[: n_frames % n_chunks] += 1
    return np.concatenate([[0], np.cumsum(sizes)])


def _chunk_encoder(params: dict[str, Any]) -> PhaseEncoder:
    return PhaseEncoder(**{k: params[k] for k in _ENCODER_PARAMS if k in params}, normalize=False)


def as_front_end(front: FrontEnd | Normalizer) -> FrontEnd:
    """A route's front-end (a bare :class:`Normalizer` is a front-end without projection)."""
    return FrontEnd(front) if isinstance(front, Normalizer) else front


def _identity(rows: np.ndarray) -> np.ndarray:
    return rows


def fit_front_end(X: np.ndarray, params: dict[str, Any], bounds: np.ndarray | None = None) -> FrontEnd:
    """The route-wide front-end every chunk shares: normaliser, then the projection (with
    ``auto_width`` and the chunks' ``bounds``, at the width chosen from the route and the
    whole model's bytes, :mod:`service.encoding.projection_width`)."""
    front = {k: params[k] for k in ("dtype", *_FRONT_PARAMS) if k in params}
    if front.get("auto_width") and front.get("n_components") and bounds is not None:
        encoder = _chunk_encoder(params)
        classes = [len(bounds) - 1, *(p for n in np.diff(bounds) for p in encoder.periods_for(int(n)))]
        front["n_components"] = choose_width(int(front["n_components"]), int(bounds[-1]), X.shape[0],
                                             X.shape[1], classes, str(front["dtype"])).width  # fmt: skip
    return FrontEnd.of_params(X, front)


def fit_chunk_encoder(
    X_chunk: np.ndarray,
    front: FrontEnd | Normalizer,
    params: dict[str, Any],
    progress: ProgressFn | None = None,
    places: np.ndarray | None = None,
) -> PhaseEncoder:
    """Train one chunk's encoder on that chunk's raw rows only; ``places`` gives each row's
    place counted from the chunk's first (``None``: row i is place i)."""
    Xc = as_front_end(front).transform_blocks(X_chunk)
    return _chunk_encoder(params)._fit_normalised(Xc, progress, places)


def fit_chunk_classifier(
    X: np.ndarray,
    bounds: np.ndarray,
    front: FrontEnd | Normalizer,
    params: dict[str, Any],
    progress: ProgressFn | None = None,
    places: np.ndarray | None = None,
) -> tuple[DigitClassifier, ClassTally | None]:
    """Pattern-learned linear classifier whose classes are the chunk ids (``progress``
    counts one unit per chunk), and its per-chunk counts when it is a prototype classifier
    (what appending needs); ``places`` gives each row's place (``None``: row i is place i),
    and every row learns its place's chunk.

    The BCSS comes from per-chunk means computed a chunk (or a row block) at a time; only
    the ``d̃`` selected columns of all rows are ever materialised.
    """
    front = as_front_end(front)
    n_chunks = len(bounds) - 1
    projected = None  # the projected route, when a projection makes rows narrower
    if front.projection is not None:
        projected = front.transform_blocks(X)
        X, transform = projected, _identity
    else:
        transform = front.transform
    if places is None:
        labels = np.repeat(np.arange(n_chunks), np.diff(bounds))
        sizes = np.diff(bounds).astype(np.float64)
        means = np.stack(
            [transform(X[s:e]).mean(axis=0) for s, e in zip(bounds[:-1], bounds[1:])]
        )
    else:
        labels = chunk_of(places, bounds)
        sizes, means = group_means(X, labels, n_chunks, transform)
    grand = sizes @ means / sizes.sum()
    scores = np.einsum("c,cd->d", sizes, (means - grand) ** 2)
    rho = params.get("chunk_rho") or params.get("rho", 0.5)
    pattern = select_columns(scores, rho, params.get("gamma"))
    cols = pattern.columns
    X_sel = np.empty((X.shape[0], cols.size))  # filled in row blocks: no full-width temporary
    norm = front.normalizer
    if projected is not None:
        X_sel[:] = projected[:, cols]
    elif norm is not None:
        mean, scale = norm.mean[cols].astype(np.float64), norm.scale[cols].astype(np.float64)
        for s in range(0, X.shape[0], _BLOCK_ROWS):
            block = np.asarray(X[s : s + _BLOCK_ROWS], dtype=np.float64)[:, cols]
            X_sel[s : s + _BLOCK_ROWS] = (block - mean) / scale
    else:
        X_sel[:] = np.asarray(X, dtype=np.float64)[:, cols]
    trainer = params.get("trainer", "logreg")
    return DigitClassifier.fit_selected(
        X_sel,
        labels,
        n_chunks,
        pattern,
        trainer=trainer,
        C=per_place_C(params.get("C", 4.0), int(bounds[-1]), X.shape[0]),
        dtype=params.get("dtype", "float32"),
        random_state=params.get("random_state", 0),
        n_jobs=params.get("n_jobs", 1),
        progress=Steps(progress, [""], [n_chunks]).step(0),
        temperature=_chunk_encoder(params)._temperature(),
    ), classifier_tally(trainer, X_sel, labels, n_chunks)


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
            **{k: getattr(self, k) for k in (*_ENCODER_PARAMS, *_FRONT_PARAMS)}
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
        encoder = _chunk_encoder(params)
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
        enc_params = {k: params[k] for k in _ENCODER_PARAMS if k in params}
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

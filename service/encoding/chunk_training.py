"""The building blocks of training a chunked model (:mod:`service.encoding.chunked`), public
so that a distributed queue can run one chunk per job and assemble the result: the chunk
boundaries, the route-wide front-end every chunk shares, one chunk's encoder, and the chunk
classifier. Each trains on the rows of its own places only (of every traversal,
:mod:`service.encoding.traversals`).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from service.encoding.appending import ClassTally
from service.encoding.chunked_appending import classifier_tally
from service.encoding.digit_classifier import DigitClassifier
from service.encoding.encoder import PhaseEncoder
from service.encoding.front_end import FrontEnd
from service.encoding.normalization import Normalizer
from service.encoding.patterns import select_columns
from service.encoding.progress import ProgressFn, Steps
from service.encoding.projection_width import choose_width
from service.encoding.traversals import check_rows, chunk_of, group_means, per_place_C
from service.errors import InvalidParameterError

ENCODER_PARAMS = (
    "n_patterns", "periods", "rho", "gamma", "trainer", "C", "decode", "beam_width", "dtype",
    "random_state", "code", "code_ratio", "code_exponent", "temperature",
)  # fmt: skip
FRONT_PARAMS = ("n_components", "whiten_power", "auto_width")  # the route's, not each chunk's


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


def chunk_encoder(params: dict[str, Any]) -> PhaseEncoder:
    """An unfitted encoder of one chunk, with the route's encoder parameters (the chunks
    share the route's front-end, so it does not normalise)."""
    return PhaseEncoder(**{k: params[k] for k in ENCODER_PARAMS if k in params}, normalize=False)


def as_front_end(front: FrontEnd | Normalizer) -> FrontEnd:
    """A route's front-end (a bare :class:`Normalizer` is a front-end without projection)."""
    return FrontEnd(front) if isinstance(front, Normalizer) else front


def _identity(rows: np.ndarray) -> np.ndarray:
    return rows


def fit_front_end(X: np.ndarray, params: dict[str, Any], bounds: np.ndarray | None = None) -> FrontEnd:
    """The route-wide front-end every chunk shares: normaliser, then the projection (with
    ``auto_width`` and the chunks' ``bounds``, at the width chosen from the route and the
    whole model's bytes, :mod:`service.encoding.projection_width`)."""
    front = {k: params[k] for k in ("dtype", *FRONT_PARAMS) if k in params}
    if front.get("auto_width") and front.get("n_components") and bounds is not None:
        encoder = chunk_encoder(params)
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
    return chunk_encoder(params)._fit_normalised(Xc, progress, places)


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
        temperature=chunk_encoder(params)._temperature(),
    ), classifier_tally(trainer, X_sel, labels, n_chunks)

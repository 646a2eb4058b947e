"""Appending traversals to a chunked model (:class:`~service.encoding.chunked.ChunkedPlaceEncoder`).

A chunked prototype model is a chunk classifier whose classes are the chunks (class means
over its selected columns) and one phase encoder per chunk (class means over the places of
the chunk), all behind one route-wide front-end. Appending a traversal is then the running-
mean update of :mod:`service.encoding.appending` twice: each new row, through the fixed front-
end, updates its chunk's class in the chunk classifier and its place's classes in its chunk's
encoder, from the per-class counts and masses the artifact keeps (``chunk_clf_tally`` and
each chunk's ``chunk.{c}.enc.{j}``). Time is proportional to the new rows (one front-end
pass, then the classes they touch).

What it does not do: extend the route (the chunk bounds would move, and with them every
chunk's places: a retrain), or learn a condition whitening (the chunks share one projection;
the default ``whiten`` of a model with one class per place applies to unchunked models only).
A model trained before its artifact kept these counts is refused until retrained once.
"""

from __future__ import annotations

import copy
from typing import Any

import numpy as np

from service.encoding.appending import (
    _BLOCK_ROWS,
    ClassTally,
    append_to_digit,
    check_appendable,
    check_new_places,
    new_rows,
)
from service.encoding.conditions import record
from service.encoding.traversals import chunk_of
from service.errors import InvalidParameterError, RetrainRequiredError

TALLY_PREFIX = "chunk_clf_tally"


def append(model: Any, X: Any, places: Any, extend: bool, whiten: bool | None,
           condition: str | None = None) -> None:  # fmt: skip
    """:meth:`ChunkedPlaceEncoder.partial_fit`'s work; mutates ``model`` only once every
    part has taken the rows."""
    if whiten:
        raise InvalidParameterError(
            "condition whitening is learnt by unchunked models only (the chunks share one "
            "projection); append to this chunked model without it"
        )
    for enc in model.chunk_encoders_:
        check_appendable(enc)
    tally: ClassTally | None = getattr(model, "chunk_tally_", None)
    if tally is None:
        raise InvalidParameterError(
            "this chunked model stores no per-chunk counts for its chunk classifier (its "
            "artifact has no append state); retrain it once to append traversals to it"
        )
    new = new_rows(X, places, model.n_features_in_)
    n = int(model.n_frames_)
    if new.places.size and int(new.places.max()) >= n:
        if not extend:
            check_new_places(new.places, n, False)  # raises, naming the first row beyond
        raise RetrainRequiredError(
            f"a chunked map's chunks are ranges of its {n} places; places beyond them move "
            "the chunk bounds and every chunk's places, so the extended route needs a full "
            "retrain", n_places=n,
        )  # fmt: skip
    recorded = record(getattr(model, "conditions_", None), condition, new.rows)
    Xn = model.normalizer_.transform_blocks(new.rows, _BLOCK_ROWS)
    bounds = model.chunk_bounds_
    chunks = chunk_of(new.places, bounds)
    clf = model.chunk_classifier_
    classifier, chunk_tally = append_to_digit(clf, tally, Xn[:, clf.columns], chunks, clf.n_classes)
    encoders = list(model.chunk_encoders_)
    for c in np.unique(chunks):
        rows = chunks == c
        enc = copy.deepcopy(encoders[c])
        enc.partial_fit(Xn[rows], places=new.places[rows] - int(bounds[c]), whiten=False)
        encoders[c] = enc
    model.chunk_classifier_, model.chunk_tally_ = classifier, chunk_tally
    model.chunk_encoders_ = encoders
    model.conditions_ = recorded
    model._set_fitted(n, model.n_features_in_, model.n_traversals_ + new.n_traversals)


def state_arrays(model: Any) -> dict[str, np.ndarray]:
    """A chunked model's append state: each chunk encoder's tallies and the chunk classifier's."""
    from service.encoding import appending

    out: dict[str, np.ndarray] = {}
    for c, enc in enumerate(model.chunk_encoders_):
        out.update(appending.state_arrays(enc, f"chunk.{c}."))
    tally = getattr(model, "chunk_tally_", None)
    if out and tally is not None:
        out.update(tally.to_arrays(TALLY_PREFIX))
    return out


def classifier_tally(trainer: str, X_sel: np.ndarray, labels: np.ndarray, n_chunks: int) -> ClassTally | None:
    """The chunk classifier's per-chunk counts and masses (prototype classifiers only)."""
    return ClassTally.of(X_sel, labels, n_chunks) if trainer == "prototype" else None

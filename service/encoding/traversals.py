"""Training input of several traversals of the same places.

A route may be driven several times (summer and winter, day and night). ``fit`` accepts

- one array: its rows are the places in route order (row ``i`` is place ``i``);
- a list or tuple of arrays of one shape: frame-aligned traversals (row ``i`` of every array
  is place ``i``);
- either of those with ``places``: for one array, one integer array giving each row's place;
  for a list, one such array per traversal (its traversals may then differ in length);
- a :class:`Traversals` that :func:`as_traversals` validated already.

Places are ``0 … N−1`` and every place needs at least one row. Every row is labelled with
its place, so every traversal trains the same encoders, and the normalisation statistics
come from all rows. ``n_traversals`` is the number of arrays given.

The trainers minimise ``½||w||² + C·Σ loss`` over the rows; with several rows per place the
loss term grows with the rows, so ``C`` is scaled by ``N / rows`` (:func:`per_place_C`):
``C`` keeps the meaning it has for one traversal, and two identical traversals train one
traversal's model.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from service.encoding.validation import check_descriptors
from service.errors import DimensionMismatchError, EmptyInputError, InvalidInputError

_BLOCK_ROWS = 65536  # rows checked or normalised at a time
WHAT = "training descriptors"


@dataclass(frozen=True)
class Traversals:
    """Validated training rows of one or more traversals, stacked."""

    rows: np.ndarray  # (n_rows, d): all traversals one after another
    places: np.ndarray | None  # int64 (n_rows,) place of every row; None: row i is place i
    n_places: int
    n_traversals: int

    @property
    def n_features(self) -> int:
        return int(self.rows.shape[1])

    def labels(self) -> np.ndarray:
        """The place of every row (``arange`` for one traversal without an index)."""
        return np.arange(self.n_places) if self.places is None else self.places


def is_several(X: Any) -> bool:
    """Whether ``X`` is a list/tuple of 2-D arrays (traversals) rather than one array
    (a list of rows is one array)."""
    if not isinstance(X, list | tuple) or len(X) == 0:
        return False
    try:
        return all(np.ndim(x) == 2 for x in X)
    except ValueError:  # ragged nested lists: one (bad) array
        return False


def check_rows(X: Any, what: str = WHAT, min_rows: int = 2, keep_dtype: bool = False) -> np.ndarray:
    """Validated rows of one traversal: float64, or with ``keep_dtype`` a float32/float64
    array (a read-only memory map of a large route) checked in row blocks and kept as it is."""
    if not (keep_dtype and isinstance(X, np.ndarray) and X.dtype in (np.float32, np.float64)
            and X.ndim == 2):  # fmt: skip
        return check_descriptors(X, min_rows=min_rows, what=what)
    check_descriptors(X[:min_rows], min_rows=min_rows, what=what)  # shape and emptiness
    for s in range(0, X.shape[0], _BLOCK_ROWS):
        check_descriptors(X[s : s + _BLOCK_ROWS], what=what)
    return X


def as_traversals(
    X: Any, places: Any = None, keep_dtype: bool = False, names: Sequence[str] | None = None
) -> Traversals:
    """Validate training input (see the module docstring) and stack it.

    Raises :class:`DimensionMismatchError` for traversals of different widths, or of
    different lengths without ``places``, and :class:`InvalidInputError` for a bad index.
    A :class:`Traversals` (already validated) is returned as it is. ``names`` (file names,
    upload fields) are quoted beside the traversal numbers in messages.
    """
    if isinstance(X, Traversals):
        if places is not None:
            raise InvalidInputError("validated traversals carry their places; give no places")
        return X
    if not is_several(X):
        if isinstance(X, list | tuple) and len(X) == 0:
            raise EmptyInputError("no traversals given: pass one array or a list of arrays")
        if is_index_list(places):
            if len(places) != 1:
                raise InvalidInputError(
                    f"{len(places)} place-index arrays given for one traversal; give one",
                    traversals=1, place_indices=len(places),
                )  # fmt: skip
            places = places[0]
        rows = check_rows(X, min_rows=1 if places is not None else 2, keep_dtype=keep_dtype)
        if places is None:
            return Traversals(rows, None, int(rows.shape[0]), 1)
        idx = check_places(places, rows.shape[0], "the place index")
        return Traversals(rows, idx, count_places(idx, rows.shape[0]), 1)
    def name(i: int) -> str:  # 1-based
        return f"traversal {i}" + (f" ({names[i - 1]})" if names and len(names) >= i else "")

    parts = [
        check_rows(x, f"{name(i + 1)} of the {WHAT}", 1 if places is not None else 2, keep_dtype)
        for i, x in enumerate(X)
    ]  # fmt: skip
    first = parts[0].shape
    for i, p in enumerate(parts[1:], start=2):
        if p.shape[1] != first[1]:
            raise DimensionMismatchError(
                f"{name(i)} has {p.shape[1]} columns but {name(1)} has {first[1]}: "
                "every traversal needs descriptors of one width",
                traversal=i, columns=int(p.shape[1]), expected=int(first[1]),
            )  # fmt: skip
        if places is None and p.shape[0] != first[0]:
            raise DimensionMismatchError(
                f"{name(i)} has {p.shape[0]} rows but {name(1)} has {first[0]}: "
                "traversals without a place index must be frame-aligned (one row per place, "
                "same length); give a place index per traversal otherwise",
                traversal=i, rows=int(p.shape[0]), expected=int(first[0]),
            )  # fmt: skip
    rows = parts[0] if len(parts) == 1 else np.concatenate(parts, axis=0)
    if places is None:
        n = int(first[0])
        idx = None if len(parts) == 1 else np.tile(np.arange(n, dtype=np.int64), len(parts))
        return Traversals(rows, idx, n, len(parts))
    if not is_index_list(places) or len(places) != len(parts):
        given = len(places) if is_index_list(places) else 1
        raise InvalidInputError(
            f"{len(parts)} traversals need {len(parts)} place-index arrays (one per "
            f"traversal), got {given}", traversals=len(parts), place_indices=given,
        )  # fmt: skip
    idx = np.concatenate([
        check_places(pl, p.shape[0], f"the place index of {name(i + 1)}")
        for i, (pl, p) in enumerate(zip(places, parts, strict=True))
    ])  # fmt: skip
    return Traversals(rows, idx, count_places(idx, rows.shape[0]), len(parts))


def is_index_list(places: Any) -> bool:
    """Whether ``places`` is a list/tuple of 1-D index arrays (one per traversal)."""
    if not isinstance(places, list | tuple) or len(places) == 0:
        return False
    try:
        return all(np.ndim(p) == 1 for p in places)
    except ValueError:
        return False


def check_places(places: Any, n_rows: int, what: str = "the place index") -> np.ndarray:
    """One traversal's place index as int64, or a precise error: 1-D, integer, one entry per
    row, no negative entry, none beyond int64."""
    try:
        idx = np.asarray(places)
    except (ValueError, TypeError) as exc:
        raise InvalidInputError(f"{what} is not a 1-D integer array: {exc}") from exc
    if idx.ndim != 1:
        raise DimensionMismatchError(
            f"{what} must be a 1-D array (one place per row), got shape {list(idx.shape)}",
            shape=list(idx.shape),
        )
    if idx.dtype.kind not in "iu":
        raise InvalidInputError(f"{what} must hold integers, got dtype {idx.dtype}")
    if idx.shape[0] != n_rows:
        raise DimensionMismatchError(
            f"{what} has {idx.shape[0]} entries but its traversal has {n_rows} rows: "
            "give one place per row", entries=int(idx.shape[0]), rows=int(n_rows),
        )  # fmt: skip
    if idx.size and idx.min() < 0:
        row = int(np.argmax(idx < 0))
        raise InvalidInputError(
            f"{what} has a negative place {int(idx[row])} at row {row}: places are 0…N−1",
            row=row,
        )
    if idx.dtype.kind == "u" and idx.size and idx.max() > np.iinfo(np.int64).max:
        row = int(np.argmax(idx > np.iinfo(np.int64).max))
        raise InvalidInputError(
            f"{what} has place {int(idx[row])} at row {row}, beyond any route: places are 0…N−1",
            row=row,
        )
    return idx.astype(np.int64, copy=False)


def count_places(idx: np.ndarray, n_rows: int) -> int:
    """``N = max + 1`` of a stacked place index, checked: at least 2 places, every place
    0…N−1 with a row (so ``N ≤ n_rows``)."""
    n = int(idx.max()) + 1 if idx.size else 0
    if n > n_rows:
        raise InvalidInputError(
            f"the place index names place {n - 1} but there are only {n_rows} rows: places "
            f"are 0…N−1 and every place needs at least one row", n_places=n, rows=n_rows,
        )  # fmt: skip
    missing = np.flatnonzero(np.bincount(idx, minlength=n) == 0)
    if missing.size:
        shown = ", ".join(str(int(m)) for m in missing[:5])
        more = f" and {missing.size - 5} more" if missing.size > 5 else ""
        raise InvalidInputError(
            f"places {shown}{more} have no row (the index names places 0…{n - 1}): every "
            "place needs at least one row", missing=[int(m) for m in missing[:20]],
        )  # fmt: skip
    if n < 2:
        raise InvalidInputError(f"a route needs at least 2 places, the place index names {n}")
    return n


def per_place_C(C: float, n_places: int, n_rows: int) -> float:
    """The trainers' ``C`` for ``n_rows`` rows of ``n_places`` places: ``C · N / rows``
    (``C`` itself for one traversal)."""
    return float(C) if n_rows == n_places else float(C) * n_places / n_rows


def chunk_rows(places: np.ndarray, bounds: np.ndarray) -> list[np.ndarray]:
    """Row numbers of each chunk ``[bounds[c], bounds[c+1])`` of places, in row order."""
    order = np.argsort(places, kind="stable")
    starts = np.searchsorted(places[order], bounds)
    return [np.sort(order[s:e]) for s, e in zip(starts[:-1], starts[1:], strict=True)]


def chunk_of(places: np.ndarray, bounds: np.ndarray) -> np.ndarray:
    """The chunk of every row's place."""
    return np.searchsorted(bounds, places, side="right") - 1


def group_means(
    X: np.ndarray,
    labels: np.ndarray,
    n_groups: int,
    transform: Callable[[np.ndarray], np.ndarray],
) -> tuple[np.ndarray, np.ndarray]:
    """Row counts and means of ``transform(X)`` per label, in row blocks (no full-size
    temporary); every group must have a row."""
    from scipy import sparse

    sums = np.zeros((n_groups, X.shape[1]))
    for s in range(0, X.shape[0], _BLOCK_ROWS):
        lab = labels[s : s + _BLOCK_ROWS]
        onehot = sparse.csr_matrix(
            (np.ones(lab.shape[0]), (lab, np.arange(lab.shape[0]))),
            shape=(n_groups, lab.shape[0]),
        )
        sums += onehot @ transform(X[s : s + _BLOCK_ROWS])
    sizes = np.bincount(labels, minlength=n_groups).astype(np.float64)
    return sizes, sums / sizes[:, None]


"""Appending traversals to a fitted prototype model without retraining it.

A ``prototype`` digit classifier's weight row is the direction of its class's mean row
(:mod:`service.encoding.prototype`), so a new traversal moves it by a running-mean update:
with ``n_c`` rows so far and ``s_c`` their sum (its norm, the class *mass*, is stored beside
the count), the rows ``x`` of the new traversal labelled ``c`` give

    s_c ← s_c + Σ x,   n_c ← n_c + #x,   W[c] = s_c / ‖s_c‖.

The front-end (column statistics, PCA projection) stays the one fitted on the first
traversals: the new rows go through it as queries do. Appending costs one front-end pass
over the new rows plus the update of the classes they touch (the rows of the other classes
are copied unchanged, bit for bit in their stored dtype): time proportional to the new
traversal, not to the map. A refit (``fit`` on every traversal) also refits the front-end
on the new traversal's statistics; it needs every traversal's rows again and costs a full
training.

**Extending the route.** Places ``N … N'−1`` beyond the route (a route driven further) need
``extend=True`` and a row each. Existing places keep their index and their labels: a code
whose one period is the route (``k = 1``, the default) grows its period to ``N'``; a code
with several periods keeps them while they still tell ``N'`` places apart (residue: lcm of
the periods ``≥ N'``; mixed radix: their product ``≥ N'``), and otherwise
:class:`RetrainRequiredError` says that a full retrain is needed (new periods relabel the
existing frames).

The per-class counts and masses (8 B per class) are the model's *append state*: stored in
the artifact beside the tensors (:mod:`service.encoding.artifacts`), never read by queries,
and outside the model's footprint.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from service.encoding.digit_classifier import DigitClassifier
from service.encoding.quantization import QuantizedLinear
from service.encoding.traversals import check_places, check_rows, is_index_list, is_several
from service.errors import DimensionMismatchError, InvalidInputError, InvalidParameterError
from service.errors import RetrainRequiredError

_MIN_NORM = 1e-12
_BLOCK_ROWS = 8192  # new rows projected at a time


@dataclass(frozen=True)
class ClassTally:
    """Rows seen per class and the norm of their sum: what a running-mean update needs."""

    counts: np.ndarray  # uint32 (n_classes,)
    mass: np.ndarray  # float64 (n_classes,), ‖Σ rows‖ of the class (0 without rows)

    @classmethod
    def of(cls, X_sel: np.ndarray, labels: np.ndarray, n_classes: int) -> ClassTally:
        sums = class_sums(X_sel, labels, n_classes)
        counts = np.bincount(labels, minlength=n_classes).astype(np.uint32)
        return cls(counts, np.sqrt(np.einsum("ij,ij->i", sums, sums)))

    def to_arrays(self, prefix: str) -> dict[str, np.ndarray]:
        return {f"{prefix}.counts": self.counts.astype(np.uint32),
                f"{prefix}.mass": self.mass.astype(np.float64)}  # fmt: skip

    @classmethod
    def from_arrays(cls, arrays: dict[str, np.ndarray], prefix: str) -> ClassTally | None:
        if f"{prefix}.counts" not in arrays:
            return None
        return cls(np.asarray(arrays[f"{prefix}.counts"], np.uint32),
                   np.asarray(arrays[f"{prefix}.mass"], np.float64))  # fmt: skip


def class_sums(X: np.ndarray, labels: np.ndarray, n_classes: int) -> np.ndarray:
    """``(n_classes, d)`` sums of the rows of each label (float64)."""
    from scipy import sparse

    onehot = sparse.csr_matrix((np.ones(labels.shape[0]), (labels, np.arange(labels.shape[0]))),
                               shape=(n_classes, labels.shape[0]))  # fmt: skip
    return np.asarray(onehot @ X, dtype=np.float64)


@dataclass(frozen=True)
class NewRows:
    """Validated rows of the traversals to append, with the place of every row."""

    rows: np.ndarray  # (n_rows, d) float64
    places: np.ndarray  # int64 (n_rows,)
    n_traversals: int


def new_rows(X: Any, places: Any, n_features: int) -> NewRows:
    """One traversal (an array) or several (a list), each with its place index (``None``:
    row ``i`` is place ``i``), validated against the model's width."""
    parts = list(X) if is_several(X) else [X]
    if places is None:
        place_list: list[Any] = [None] * len(parts)
    elif is_index_list(places) and is_several(X):
        place_list = list(places)
    elif not is_several(X):
        place_list = [places[0] if is_index_list(places) and len(places) == 1 else places]
    else:
        raise InvalidInputError(
            f"{len(parts)} traversals need {len(parts)} place-index arrays (one per traversal)"
        )
    if len(place_list) != len(parts):
        raise InvalidInputError(
            f"{len(parts)} traversals need {len(parts)} place-index arrays, got {len(place_list)}"
        )
    rows, idx = [], []
    for i, (x, pl) in enumerate(zip(parts, place_list, strict=True)):
        what = "the descriptors to append" + (f" (traversal {i + 1})" if len(parts) > 1 else "")
        r = check_rows(x, what, min_rows=1)
        if r.shape[1] != n_features:
            raise DimensionMismatchError(
                f"{what} have {r.shape[1]} columns but the map's descriptors have "
                f"{n_features}: append traversals of the map's own descriptor",
                columns=int(r.shape[1]), expected=int(n_features),
            )  # fmt: skip
        rows.append(r)
        idx.append(np.arange(r.shape[0], dtype=np.int64) if pl is None
                   else check_places(pl, r.shape[0], f"the place index of {what}"))  # fmt: skip
    return NewRows(np.concatenate(rows) if len(rows) > 1 else rows[0],
                   np.concatenate(idx) if len(idx) > 1 else idx[0], len(parts))  # fmt: skip


def check_new_places(places: np.ndarray, n_frames: int, extend: bool) -> int:
    """The route's length after appending: ``N``, or with ``extend`` the places beyond it,
    each of which needs a row."""
    top = int(places.max()) + 1 if places.size else 0
    if top <= n_frames:
        return n_frames
    if not extend:
        row = int(np.argmax(places >= n_frames))
        raise InvalidInputError(
            f"place {int(places[row])} (row {row}) is beyond the route's places 0…{n_frames - 1}; "
            "extend the route (extend=True) to append places beyond it",
            row=row, place=int(places[row]), n_places=int(n_frames),
        )  # fmt: skip
    seen = np.zeros(top - n_frames, dtype=bool)
    seen[places[places >= n_frames] - n_frames] = True
    if not seen.all():
        missing = np.flatnonzero(~seen)[:5] + n_frames
        raise InvalidInputError(
            f"the route is extended to {top} places but places {', '.join(map(str, missing))} "
            "have no row: every new place needs a row", missing=[int(m) for m in missing],
        )  # fmt: skip
    return top


def extended_periods(code: str, periods: tuple[int, ...], n_old: int, n_new: int) -> tuple[int, ...]:
    """Periods that label ``n_new`` places and keep every existing place's labels."""
    if n_new == n_old:
        return periods
    if len(periods) == 1 and periods[0] == max(2, n_old):
        return (n_new,)  # one class per place: the new places are new classes
    capacity = math.lcm(*periods) if code == "residue" else math.prod(periods)
    if capacity >= n_new:
        return periods
    raise RetrainRequiredError(
        f"the code's periods {periods} tell {capacity} places apart, fewer than the "
        f"{n_new} of the extended route; periods for {n_new} places would relabel the existing "
        "frames, so the extended route needs a full retrain",
        periods=list(periods), capacity=int(capacity), n_places=int(n_new),
    )  # fmt: skip


def append_to_digit(
    dc: DigitClassifier, tally: ClassTally, X_sel: np.ndarray, labels: np.ndarray,
    n_classes: int,
) -> tuple[DigitClassifier, ClassTally]:  # fmt: skip
    """The digit after the running-mean update of the classes ``labels`` touch (``n_classes``
    may exceed the digit's: new classes are appended)."""
    old_n = dc.n_classes
    counts = np.zeros(n_classes, np.uint32)
    counts[:old_n] = tally.counts
    mass = np.zeros(n_classes)
    mass[:old_n] = tally.mass
    touched = np.unique(labels)
    lab = np.searchsorted(touched, labels)
    add = class_sums(X_sel, lab, touched.size)
    W_old, _ = dc.linear.dense
    old = touched[touched < old_n]
    prior = np.zeros((touched.size, W_old.shape[1]))
    if old.size:
        rows = W_old[old]
        norms = np.sqrt(np.einsum("ij,ij->i", rows, rows))[:, None]
        prior[: old.size] = rows / np.maximum(norms, _MIN_NORM) * mass[old, None]
    sums = prior + add  # touched is sorted, so the old classes come first
    counts[touched] += np.bincount(lab, minlength=touched.size).astype(np.uint32)
    mass[touched] = np.sqrt(np.einsum("ij,ij->i", sums, sums))
    W_new = sums / np.maximum(mass[touched, None], _MIN_NORM)
    linear = replace_rows(dc.linear, n_classes, touched, W_new)
    out = DigitClassifier(dc.columns, linear, dc.pattern, dc.temperature)
    return out, ClassTally(counts, mass)


def replace_rows(
    linear: QuantizedLinear, n_rows: int, rows: np.ndarray, W: np.ndarray
) -> QuantizedLinear:
    """``linear`` grown to ``n_rows`` rows with ``rows`` replaced by ``W`` (bias 0), the
    others kept in their stored form; new rows not in ``rows`` score ``−inf``."""
    q = QuantizedLinear.from_dense(W, np.zeros(W.shape[0]), linear.dtype)
    old_n = linear.weight.shape[0]
    weight = np.zeros((n_rows, linear.weight.shape[1]), linear.weight.dtype)
    weight[:old_n] = linear.weight
    weight[rows] = q.weight
    bias = np.full(n_rows, -np.inf, linear.bias.dtype)
    bias[:old_n] = linear.bias
    bias[rows] = q.bias
    scale = None
    if linear.scale is not None and q.scale is not None:
        scale = np.ones(n_rows, np.float32)
        scale[:old_n] = linear.scale
        scale[rows] = q.scale
    return QuantizedLinear(weight=weight, bias=bias, scale=scale)


def check_appendable(model: Any) -> list[ClassTally]:
    """The model's append state, or why it cannot be appended to."""
    if getattr(model, "trainer", None) != "prototype":
        raise InvalidParameterError(
            f"partial_fit updates prototype classifiers (class means); this model's trainer is "
            f"{getattr(model, 'trainer', None)!r}, whose classifiers need a full retrain"
        )
    tallies = getattr(model, "tallies_", None)
    if not tallies or any(t is None for t in tallies):
        raise InvalidParameterError(
            "this model stores no per-class counts (its artifact has no append state); "
            "retrain it once to append traversals to it"
        )
    return list(tallies)


def transform_rows(front: Any, X: np.ndarray) -> np.ndarray:
    """The new rows through the model's fixed front-end, in row blocks."""
    if front is None:
        return np.asarray(X, np.float64)
    return front.transform_blocks(X, _BLOCK_ROWS)


# -- condition whitening ---------------------------------------------------------------------
WHITEN_FLOOR = 0.1  # of the mean eigenvalue, added before the inverse square root


@dataclass(frozen=True)
class ConditionWhitening:
    """Within-place scatter of appended traversals in the projected space, and the projection
    as fitted (before any whitening): ``T = U·diag(λ/mean λ + floor)^−½·Uᵀ`` of the scatter
    ``Σ (z − p)(z − p)ᵀ / n`` of every appended row ``z`` against its place's prototype
    ``p`` (both unit vectors, before the row is added), folded into the stored projection."""

    scatter: np.ndarray  # (m, m) float64, sum of outer products
    rows: int
    base: QuantizedLinear  # the projection as fitted: (m, d) weights, (m,) bias

    def matrix(self) -> np.ndarray:
        """``T`` (identity before any row)."""
        m = self.scatter.shape[0]
        if self.rows == 0:
            return np.eye(m)
        ev, U = np.linalg.eigh(self.scatter / self.rows)
        ev = np.maximum(ev, 0.0)
        return (U * (ev / max(float(ev.mean()), _MIN_NORM) + WHITEN_FLOOR) ** -0.5) @ U.T

    def add(self, D: np.ndarray) -> ConditionWhitening:
        return ConditionWhitening(self.scatter + D.T @ D, self.rows + int(D.shape[0]), self.base)

    def projection(self, T: np.ndarray) -> QuantizedLinear:
        """The base projection followed by ``T``, at the base's storage dtype."""
        W, b = self.base.dense
        return QuantizedLinear.from_dense(T @ W, T @ b, self.base.dtype)

    def to_arrays(self, prefix: str = "whiten") -> dict[str, np.ndarray]:
        out = {f"{prefix}.scatter": self.scatter, f"{prefix}.rows": np.array([self.rows], np.int64)}
        out.update(self.base.to_arrays(f"{prefix}.base"))
        return out

    @classmethod
    def from_arrays(cls, arrays: dict[str, np.ndarray], prefix: str = "whiten") -> ConditionWhitening | None:
        if f"{prefix}.scatter" not in arrays:
            return None
        return cls(np.asarray(arrays[f"{prefix}.scatter"], np.float64),
                   int(arrays[f"{prefix}.rows"][0]),
                   QuantizedLinear.from_arrays(arrays, f"{prefix}.base"))  # fmt: skip


def _unit(Z: np.ndarray) -> np.ndarray:
    return Z / np.maximum(np.sqrt(np.einsum("ij,ij->i", Z, Z))[:, None], _MIN_NORM)


def can_whiten(model: Any) -> bool:
    """Condition whitening needs one class per place (``k = 1``), a projection, and digits
    that read every projected column."""
    front = getattr(model, "normalizer_", None)
    if front is None or front.projection is None or len(model.digits_) != 1:
        return False
    dc = model.digits_[0]
    return model.periods_[0] == model.n_frames_ and dc.columns.size == front.projection.n_components


def append(model: Any, X: Any, places: Any, extend: bool, whiten: bool | None,
           condition: str | None = None) -> None:  # fmt: skip
    """:meth:`PhaseEncoder.partial_fit`'s work (see there); mutates ``model``."""
    from service.encoding.conditions import record
    from service.encoding.front_end import FrontEnd
    from service.encoding.projection import Projection

    tallies = check_appendable(model)
    new = new_rows(X, places, model.n_features_in_)
    recorded = record(getattr(model, "conditions_", None), condition, new.rows)
    n_new = check_new_places(new.places, model.n_frames_, extend)
    periods = extended_periods(model.code, model.periods_, model.n_frames_, n_new)
    if whiten is None:
        whiten = can_whiten(model)
    elif whiten and not can_whiten(model):
        raise InvalidParameterError(
            "condition whitening needs a projected model with one class per place (k = 1, "
            "the default); append without it (whiten=False)"
        )
    if not whiten:
        Xn = transform_rows(model.normalizer_, new.rows)
        labels = model_labels(model, new.places, periods)
        digits, out = [], []
        for j, (dc, tally) in enumerate(zip(model.digits_, tallies, strict=True)):
            d2, t2 = append_to_digit(dc, tally, Xn[:, dc.columns], labels[:, j], periods[j])
            digits.append(d2)
            out.append(t2)
        model.digits_, model.tallies_ = digits, out
    else:
        front = model.normalizer_
        state = getattr(model, "whitening_", None)
        if state is None:
            m = front.projection.n_components
            state = ConditionWhitening(np.zeros((m, m)), 0, front.projection.linear)
        T_old = state.matrix()
        Zb = FrontEnd(front.normalizer, Projection(state.base)).transform_blocks(new.rows, _BLOCK_ROWS)
        dc, tally = model.digits_[0], tallies[0]
        n_old = dc.n_classes
        W_old, _ = dc.linear.dense
        S = np.zeros((n_new, W_old.shape[1]))
        S[:n_old] = _unit(W_old @ np.linalg.inv(T_old)) * tally.mass[:, None]
        seen = new.places < n_old
        state = state.add(Zb[seen] - _unit(S[new.places[seen]]))
        T = state.matrix()
        S += class_sums(Zb, new.places, n_new)
        counts = np.zeros(n_new, np.uint32)
        counts[:n_old] = tally.counts
        counts += np.bincount(new.places, minlength=n_new).astype(np.uint32)
        mass = np.sqrt(np.einsum("ij,ij->i", S, S))
        linear = QuantizedLinear.from_dense(_unit(S @ T), np.zeros(n_new), dc.linear.dtype)
        model.digits_ = [DigitClassifier(np.arange(W_old.shape[1]), linear, dc.pattern,
                                         dc.temperature)]  # fmt: skip
        model.tallies_ = [ClassTally(counts, mass)]
        model.normalizer_ = FrontEnd(front.normalizer, Projection(state.projection(T)))
        model.whitening_ = state
    model.periods_ = periods
    model.conditions_ = recorded
    model._set_fitted(n_new, model.n_features_in_, model.n_traversals_ + new.n_traversals)
    if hasattr(model, "_fit_inverted_file"):  # the prototypes moved: their lists are refitted
        model.ivf_ = model._fit_inverted_file()


def model_labels(model: Any, places: np.ndarray, periods: tuple[int, ...]) -> np.ndarray:
    if model.code == "residue":
        return np.asarray(places, np.int64)[:, None] % np.asarray(periods, np.int64)[None, :]
    from service.encoding.phases import index_to_labels

    return index_to_labels(places, periods)


def tallies_of(model: Any, Xn: np.ndarray, labels: np.ndarray) -> list[ClassTally] | None:
    """Per-class counts and masses of a fit's prototype digits (``None`` for other trainers)."""
    if model.trainer != "prototype":
        return None
    return [ClassTally.of(Xn[:, dc.columns], labels[:, j], dc.n_classes)
            for j, dc in enumerate(model.digits_)]  # fmt: skip


def streamed_tally(X: np.ndarray, front: Any) -> ClassTally:
    """The tally of one traversal with one class per row: a count of 1 and the norm of the
    transformed row (1 through a projection, which normalises its rows; else one more pass)."""
    n = X.shape[0]
    if front.projection is not None:
        mass = np.ones(n)
    else:
        mass = np.concatenate([np.sqrt(np.einsum("ij,ij->i", Z, Z)) for Z in (
            front.transform(X[s : s + _BLOCK_ROWS]) for s in range(0, n, _BLOCK_ROWS))])  # fmt: skip
    return ClassTally(np.ones(n, np.uint32), mass)


def state_arrays(model: Any, prefix: str = "") -> dict[str, np.ndarray]:
    """A model's append state as arrays: per-class tallies and any condition whitening."""
    out: dict[str, np.ndarray] = {}
    for j, tally in enumerate(getattr(model, "tallies_", None) or []):
        out.update(tally.to_arrays(f"{prefix}enc.{j}"))
    whitening = getattr(model, "whitening_", None)
    if out and whitening is not None:
        out.update(whitening.to_arrays(f"{prefix}whiten"))
    return out

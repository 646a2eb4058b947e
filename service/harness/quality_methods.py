"""The methods ``gridplace bench quality`` compares, all on the same descriptors in one run.

Every method is a :class:`QualityMethod`: a name, a family (for the tables and the plot),
the parameters it was built with and a zero-argument constructor of an unfitted model that
has ``fit``, ``localize``, ``frame_log_scores`` and ``footprint``: exact NN, PQ at several
``m``, Yu et al., exact NN in the projected space of the ``robust`` front-end
(:mod:`service.harness.projected_nn`) and the gridplace presets with variants of the default
along its storage axes (:data:`GRIDPLACE_CONFIGS`).

Multi-traversal training (several traversals of the same places, each row labelled with its
place) goes through :func:`fit_places`: gridplace models take ``places=`` themselves; the
storage-linear baselines (exact NN, PQ, Yu et al.) are wrapped in :class:`PlacePooled`,
which stores every training row as its own reference and scores a place by its best row —
what a user of those methods would do with two traversals.
"""

from __future__ import annotations

import inspect
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from service.encoding import ExactNN, ModelParams, PQIndex, RhythmicEncoder, build_model
from service.encoding.base import Localization
from service.encoding.footprint import Footprint
from service.encoding.pq import faiss_available
from service.errors import InvalidParameterError
from service.harness.projected_nn import ProjectedNN

FAMILIES: tuple[str, ...] = ("exact_nn", "exact_nn_projected", "pq", "yu", "gridplace")
FAMILY_LABELS = {
    "exact_nn": "exact NN",
    "exact_nn_projected": "exact NN (projected)",
    "pq": "PQ (faiss)",
    "yu": "Yu et al. (rhythmic)",
    "gridplace": "gridplace",
}
PQ_SUBQUANTIZERS: tuple[int, ...] = (16, 32, 64)
# gridplace configurations: the named presets (service.encoding.presets) and variants along
# the two axes that set their storage: the code ratio Στ/N (residue digits, k = 2; robust's
# single digit is always the whole route) and the projection width
GRIDPLACE_CONFIGS: dict[str, dict[str, Any]] = {
    "paper": {"encoder_preset": "paper"},
    "ridge": {"encoder_preset": "ridge"},
    "residue": {"encoder_preset": "residue"},
    "robust": {"encoder_preset": "robust"},
    "residue-ratio0.5": {"encoder_preset": "residue", "code_ratio": 0.5},
    "residue-ratio0.25": {"encoder_preset": "residue", "code_ratio": 0.25},
    "robust-pca64": {"encoder_preset": "robust", "n_components": 64},
    "robust-pca128": {"encoder_preset": "robust", "n_components": 128},
}
PROJECTED_NN_COMPONENTS: tuple[int, ...] = (64, 128, 256)


@dataclass(frozen=True)
class QualityMethod:
    name: str
    family: str
    build: Callable[[], Any] = field(compare=False, repr=False)
    params: dict[str, Any] = field(default_factory=dict)


def gridplace_method(name: str, params: ModelParams) -> QualityMethod:
    return QualityMethod(name, "gridplace", lambda: build_model(params),
                         params.model_dump(mode="json"))  # fmt: skip


def baseline_methods(
    n_features: int, n_frames: int, yu_trainer: str = "ridge"
) -> list[QualityMethod]:
    """Exact NN, PQ at every ``m`` that divides ``d`` (faiss installed, ≥ 256 frames), Yu."""
    out = [QualityMethod("exact-nn", "exact_nn", ExactNN, {"dtype": "float32"})]
    if faiss_available() and n_frames >= 256:
        out += [
            QualityMethod(f"pq-m{m}", "pq", lambda m=m: PQIndex(n_subquantizers=m),
                          {"n_subquantizers": m})  # fmt: skip
            for m in PQ_SUBQUANTIZERS
            if n_features % m == 0
        ]
    out.append(QualityMethod("yu", "yu", lambda: RhythmicEncoder(trainer=yu_trainer),
                             {"n_patterns": 2, "trainer": yu_trainer}))  # fmt: skip
    robust = ModelParams.parse(encoder_preset="robust")
    out += [
        QualityMethod(f"nn-pca{m}", "exact_nn_projected",
                      lambda m=m: ProjectedNN(m, robust.whiten_power, "float32"),
                      {"n_components": m, "whiten_power": robust.whiten_power})  # fmt: skip
        for m in PROJECTED_NN_COMPONENTS
    ]
    return out


def gridplace_methods(names: list[str] | None = None) -> list[QualityMethod]:
    """The named gridplace configurations (default: all of :data:`GRIDPLACE_CONFIGS`)."""
    table = {k: ModelParams.parse(**v) for k, v in GRIDPLACE_CONFIGS.items()}
    chosen = list(table) if names is None else names
    unknown = [n for n in chosen if n not in table]
    if unknown:
        raise InvalidParameterError(
            f"unknown gridplace configuration(s) {unknown}; choose from {sorted(table)}"
        )
    return [gridplace_method(n, table[n]) for n in chosen]


def catalogue(n_features: int, n_frames: int, methods: str = "all",
              yu_trainer: str = "ridge") -> list[QualityMethod]:  # fmt: skip
    """Every method of the benchmark, or the comma-separated names/families in ``methods``."""
    every = baseline_methods(n_features, n_frames, yu_trainer) + gridplace_methods()
    if methods == "all":
        return every
    wanted = {m.strip() for m in methods.split(",") if m.strip()}
    picked = [m for m in every if m.name in wanted or m.family in wanted]
    missing = wanted - {m.name for m in picked} - {m.family for m in picked}
    if missing:
        names = sorted({m.name for m in every} | {m.family for m in every})
        raise InvalidParameterError(f"unknown method(s) {sorted(missing)}; choose from {names}")
    return picked


# -- multi-traversal ------------------------------------------------------------------------
def accepts_places(model: Any) -> bool:
    """Whether ``model.fit`` takes a ``places=`` row → place index."""
    try:
        return "places" in inspect.signature(model.fit).parameters
    except (TypeError, ValueError):
        return False


class PlacePooled:
    """A storage-linear method on several traversals: every row is a reference of its place;
    a place scores as its best row; an answer is the place of the best row."""

    def __init__(self, inner: Any) -> None:
        self.inner = inner

    def fit(self, X: np.ndarray, places: np.ndarray) -> PlacePooled:
        places = np.asarray(places, dtype=np.int64)
        self.order_ = np.argsort(places, kind="stable")
        sorted_places = places[self.order_]
        self.n_frames_ = int(sorted_places[-1]) + 1
        if not np.array_equal(np.unique(sorted_places), np.arange(self.n_frames_)):
            raise InvalidParameterError("every place needs at least one row")
        self.starts_ = np.flatnonzero(np.r_[True, np.diff(sorted_places) > 0])
        self.places_ = places
        self.inner.fit(np.asarray(X)[self.order_])
        return self

    def localize(self, X: np.ndarray) -> Localization:
        loc = self.inner.localize(X)
        index = self.places_[self.order_][loc.index]
        return Localization(index, loc.confidence, loc.chunk, loc.log_score)

    def frame_log_scores(self, X: np.ndarray) -> np.ndarray:
        S = self.inner.frame_log_scores(X)
        return np.maximum.reduceat(S, self.starts_, axis=1)

    def footprint(self) -> Footprint:
        return self.inner.footprint()


def fit_places(model: Any, X: np.ndarray, places: np.ndarray | None) -> Any:
    """``model`` fitted on rows ``X`` whose places are ``places`` (``None``: row i = place i)."""
    if places is None:
        return model.fit(X)
    if accepts_places(model):
        return model.fit(X, places=places)
    if isinstance(model, ExactNN | PQIndex | RhythmicEncoder | ProjectedNN):
        return PlacePooled(model).fit(X, places)
    raise InvalidParameterError(
        f"{type(model).__name__} cannot be fitted on several traversals (no places= in fit)"
    )

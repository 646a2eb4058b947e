"""Frame scores for a vehicle's tracker, computed only where the tracker needs them.

The whole-route filter needs every frame's score each query frame, ``O(N)`` however small the
map. A tracker (:mod:`service.encoding.tracking`) needs, per query frame, the scores of the
frames inside its windows, the spread of the scores over the route (the z-score emission's
scale) and, every few frames, a few candidate places anywhere on the route. A scorer gives
those:

- :class:`CodeScorer`, for a model with one phase encoder (no chunks): a query's evidence is
  its per-digit class log-probabilities (``Στ`` numbers); a frame's score is the sum of its
  digits' entries, a gather per frame. The spread comes from a fixed sample of frames; the
  candidates from the frames of each digit's best classes. Nothing here costs ``O(N)``: for
  a code with ``Στ ≪ N`` a tracked frame costs ``O(Στ·width + window)``.
- :class:`RowScorer`, for any other model: the model's full row of frame scores (``O(N)``).
- :class:`MatrixScorer`: rows of a precomputed ``(T, N)`` score matrix (benches, tests).
"""

from __future__ import annotations

from functools import lru_cache
from typing import Any

import numpy as np

from service.encoding.phases import index_to_labels
from service.encoding.repeats import successors
from service.encoding.sequence import check_scores

SAMPLE = 256  # frames whose scores estimate a query's spread over the route
TOP_CLASSES = 8  # classes per digit whose frames a global check considers


@lru_cache(maxsize=16)
def route_sample(n_frames: int) -> np.ndarray:
    """The frames whose scores stand for a query's spread over a route of ``n_frames``: a fixed
    random sample of :data:`SAMPLE` (every frame of a shorter route), the same for every
    scorer, so trackers on the same scores agree."""
    if n_frames <= SAMPLE:
        return np.arange(n_frames)
    rng = np.random.default_rng(0)
    return np.sort(rng.choice(n_frames, SAMPLE, replace=False))


class RowScorer:
    """Any model with ``frame_log_scores``: a prepared query is its full row of scores."""

    def __init__(self, model: Any) -> None:
        self.model = model
        self.n_frames = int(model.n_frames_)

    def prepare_many(self, Q: np.ndarray) -> list[Any]:
        return [check_scores(r, self.n_frames) for r in self.model.frame_log_scores(Q)]

    def full(self, prep: Any) -> np.ndarray:
        return prep  # type: ignore[no-any-return]

    def frames(self, prep: Any, idx: np.ndarray) -> np.ndarray:
        return prep[idx]  # type: ignore[no-any-return]

    def sample_scores(self, prep: Any) -> np.ndarray:
        """Scores of the frames that stand for the route (:func:`route_sample`)."""
        return prep[route_sample(self.n_frames)]  # type: ignore[no-any-return]

    def next_scores(self, prep: Any) -> np.ndarray:
        """Scores of the frames after the route sample's (a query's repetition test)."""
        return self.frames(prep, successors(route_sample(self.n_frames), self.n_frames))

    def candidates(self, prep: Any, m: int) -> np.ndarray:
        row = np.where(np.isfinite(prep), prep, -np.inf)
        m = min(m, row.size)
        top = np.argpartition(-row, m - 1)[:m]
        return top[np.argsort(-row[top], kind="stable")]  # type: ignore[no-any-return]

    def best(self, prep: Any) -> int:
        return int(np.argmax(prep))


class MatrixScorer(RowScorer):
    """Rows of a precomputed ``(T, N)`` score matrix; a prepared query is its row number."""

    def __init__(self, scores: np.ndarray) -> None:
        self.scores = scores
        self.n_frames = int(scores.shape[1])
        self._row: tuple[int, np.ndarray] | None = None

    def prepare_many(self, Q: np.ndarray) -> list[Any]:
        return list(np.asarray(Q).ravel())

    def _get(self, t: int) -> np.ndarray:
        if self._row is None or self._row[0] != t:
            self._row = (t, check_scores(self.scores[t], self.n_frames))
        return self._row[1]

    def full(self, prep: Any) -> np.ndarray:
        return self._get(int(prep))

    def frames(self, prep: Any, idx: np.ndarray) -> np.ndarray:
        return self._get(int(prep))[idx]

    def sample_scores(self, prep: Any) -> np.ndarray:
        return self._get(int(prep))[route_sample(self.n_frames)]

    def candidates(self, prep: Any, m: int) -> np.ndarray:
        return super().candidates(self._get(int(prep)), m)

    def best(self, prep: Any) -> int:
        return int(np.argmax(self._get(int(prep))))


class CodeScorer:
    """A one-phase model's frames scored from its digits' class scores ``β·(w_c·z + b_c)``,
    computed only for the classes asked for. A frame's score is the sum of its digits' class
    scores: the model's frame log-score up to a constant per query (each digit's softmax
    normaliser), to which the filter is invariant."""

    def __init__(self, model: Any, plan: Any) -> None:
        self.plan = plan
        phase = plan.phases[0]
        self.digits = phase.digits
        self.n_frames = int(phase.n_frames)
        #: a residue code's labels ``f mod τ_j`` and its classes' frames ``c, c + τ_j, …`` are
        #: computed; other codes keep a ``(k, N)`` table and each class's frames in order
        self.periods: tuple[int, ...] | None = tuple(phase.periods) if phase.residue else None
        self.labels: np.ndarray | None = None
        self.order: list[np.ndarray] = []
        self.starts: list[np.ndarray] = []
        if self.periods is None:
            labels = phase.labels
            if labels is None:
                labels = index_to_labels(np.arange(self.n_frames), phase.periods)
            self.labels = np.ascontiguousarray(np.asarray(labels).T, dtype=np.int32)  # (k, N)
            # frames of each class, per digit: order[j][starts[j][c]:starts[j][c + 1]]
            self.order = [np.argsort(lab, kind="stable").astype(np.int32) for lab in self.labels]
            self.starts = [
                np.searchsorted(lab[o], np.arange(dg.n_classes + 1))
                for lab, o, dg in zip(self.labels, self.order, self.digits, strict=True)
            ]
        self.sample = route_sample(self.n_frames)
        # the sample's classes per digit (and those of the frames after them, for the repetition
        # test), their rows gathered once: a query's spread over the route is one small
        # contiguous product per digit, not a gather across the whole code
        self._sample = self._gathered(self.sample)
        self._next = self._gathered(successors(self.sample, self.n_frames))

    def _gathered(self, frames: np.ndarray) -> list[_Rows]:
        return [_Rows.of(dg, self._labels(j, frames)) for j, dg in enumerate(self.digits)]

    def _labels(self, j: int, frames: np.ndarray) -> np.ndarray:
        """Digit ``j``'s class of each frame of ``frames``."""
        if self.periods is not None:
            return np.asarray(frames, dtype=np.int64) % self.periods[j]
        assert self.labels is not None
        return self.labels[j, frames]

    def _route(self, j: int, scores: np.ndarray) -> np.ndarray:
        """Every frame's score of digit ``j`` from its class scores ``scores`` (a new array)."""
        if self.periods is not None:
            return np.resize(scores, self.n_frames)  # repeated: frame f gets scores[f mod τ_j]
        assert self.labels is not None
        return scores[self.labels[j]]

    def _class_frames(self, j: int, c: int) -> np.ndarray:
        """The frames of digit ``j``'s class ``c``, ascending."""
        if self.periods is not None:
            return np.arange(c, self.n_frames, self.periods[j])
        return self.order[j][self.starts[j][c] : self.starts[j][c + 1]]

    @property
    def check_cost(self) -> int:
        """Class scores one global check (:meth:`candidates`) computes: ``Στ``."""
        return int(sum(dg.n_classes for dg in self.digits))

    def prepare_many(self, Q: np.ndarray) -> list[Any]:
        Z = self.plan.normalise(np.asarray(Q, dtype=np.float64), np.float32)
        zs = [Z.take(dg.columns, axis=1) for dg in self.digits]
        return [_Prepared([z[i] for z in zs]) for i in range(Z.shape[0])]

    def _classes(self, prep: _Prepared, j: int, cls: np.ndarray) -> np.ndarray:
        """Scores of digit ``j``'s classes ``cls`` (all of them once computed)."""
        full = prep.full[j]
        if full is not None:
            return full[cls]  # type: ignore[no-any-return]
        dg = self.digits[j]
        return _class_scores(dg, dg.weight[cls], None if dg.rowscale is None else dg.rowscale[cls],
                             dg.bias[cls], prep.z[j])  # fmt: skip

    def _all(self, prep: _Prepared, j: int) -> np.ndarray:
        full = prep.full[j]
        if full is None:
            dg = self.digits[j]
            full = dg.products(prep.z[j][None, :])[0].astype(np.float64) + dg.bias
            if dg.beta != 1.0:
                full *= dg.beta
            prep.full[j] = full
        return full

    def frames(self, prep: Any, idx: np.ndarray) -> np.ndarray:
        out = np.zeros(len(idx))
        for j in range(len(self.digits)):
            lab = self._labels(j, idx)
            if prep.full[j] is None:  # only the classes asked for: O(window), not O(Στ)
                if lab.size <= self.digits[j].n_classes:  # no more rows than the code has:
                    out += self._classes(prep, j, lab)  # a repeated class costs less than a sort
                else:
                    uniq, inv = np.unique(lab, return_inverse=True)
                    out += self._classes(prep, j, uniq)[inv]
            else:
                out += self._all(prep, j)[lab]
        return out

    def full(self, prep: Any) -> np.ndarray:
        out = self._route(0, self._all(prep, 0))
        for j in range(1, len(self.digits)):
            out += self._route(j, self._all(prep, j))
        return out

    def sample_scores(self, prep: Any) -> np.ndarray:
        """Scores of the route's sample frames (:func:`route_sample`), computed once per query
        (read-only: a tracker asks for them several times a frame)."""
        if prep.sample is None:
            out = self._fixed_scores(prep, self._sample)
            out.flags.writeable = False
            prep.sample = out
        return prep.sample

    def next_scores(self, prep: Any) -> np.ndarray:
        """Scores of the frames after the route sample's (a query's repetition test), from
        their classes' rows gathered once."""
        return self._fixed_scores(prep, self._next)

    def _fixed_scores(self, prep: _Prepared, gathered: list[_Rows]) -> np.ndarray:
        """Scores of a fixed set of frames whose classes' rows are ``gathered`` per digit."""
        out = np.zeros(gathered[0].inverse.size)
        for j, rows in enumerate(gathered):
            full = prep.full[j]
            if full is not None:
                out += full[rows.classes[rows.inverse]]
            else:
                out += rows.scores(self.digits[j], prep.z[j])[rows.inverse]
        return out

    def candidates(self, prep: Any, m: int) -> np.ndarray:
        pools = []
        for j in range(len(self.digits)):
            s = self._all(prep, j)
            t = min(TOP_CLASSES, s.size)
            top = np.argpartition(-s, t - 1)[:t]
            pools += [self._class_frames(j, int(c)) for c in top]
        pool = np.unique(np.concatenate(pools))
        s = self.frames(prep, pool)
        m = min(m, pool.size)
        top = np.argpartition(-s, m - 1)[:m]
        return pool[top[np.argsort(-s[top], kind="stable")]]  # type: ignore[no-any-return]

    def best(self, prep: Any) -> int:
        return int(self.candidates(prep, 1)[0])


class _Prepared:
    """One query's projected columns per digit, each digit's class scores once needed, and
    the route sample's scores once asked for."""

    __slots__ = ("full", "sample", "z")

    def __init__(self, z: list[np.ndarray]) -> None:
        self.z = z
        self.full: list[np.ndarray | None] = [None] * len(z)
        self.sample: np.ndarray | None = None


def _class_scores(dg: Any, weight: np.ndarray, rowscale: np.ndarray | None, bias: np.ndarray,
                  z: np.ndarray) -> np.ndarray:  # fmt: skip
    """``β·(w_c·z + b_c)`` of the classes whose rows are ``weight`` (float64)."""
    if rowscale is not None:  # int8 weights with a scale per class
        out = (weight.astype(np.float32) @ z) * rowscale
    else:
        out = weight @ z
    out = out.astype(np.float64) + bias
    return out * dg.beta if dg.beta != 1.0 else out  # type: ignore[no-any-return]


class _Rows:
    """A fixed set of one digit's classes (those of a fixed set of frames) with their rows
    gathered into one contiguous block."""

    __slots__ = ("bias", "classes", "inverse", "rowscale", "weight")

    def __init__(self, classes: np.ndarray, inverse: np.ndarray, weight: np.ndarray,
                 rowscale: np.ndarray | None, bias: np.ndarray) -> None:  # fmt: skip
        self.classes, self.inverse = classes, inverse
        self.weight, self.rowscale, self.bias = weight, rowscale, bias

    @classmethod
    def of(cls, dg: Any, labels: np.ndarray) -> _Rows:
        """The rows of the classes ``labels`` (one per frame) of digit block ``dg``."""
        classes, inverse = np.unique(labels, return_inverse=True)
        scale = None if dg.rowscale is None else dg.rowscale[classes]
        return cls(classes, inverse, np.ascontiguousarray(dg.weight[classes]), scale,
                   dg.bias[classes])  # fmt: skip

    def scores(self, dg: Any, z: np.ndarray) -> np.ndarray:
        """The classes' scores for one query's projected columns ``z``."""
        return _class_scores(dg, self.weight, self.rowscale, self.bias, z)


def drive_scorer(model: Any) -> RowScorer | CodeScorer:
    """The model's scorer for trackers: a :class:`CodeScorer` for one-phase models of
    :mod:`service.encoding`, else a :class:`RowScorer`; built on first use and kept until the
    model is refitted."""
    scorer = model.__dict__.get("_drive_scorer")
    if scorer is None:
        scorer = RowScorer(model)
        from service.encoding.encoder import PhaseEncoder

        plain = type(model).frame_log_scores is PhaseEncoder.frame_log_scores
        if isinstance(model, PhaseEncoder) and plain:  # frame scores are its serving plan's
            from service.encoding.serving_plan import plan_for

            plan = plan_for(model)
            if plan.chunk is None and len(plan.phases) == 1:
                scorer = CodeScorer(model, plan)
        model.__dict__["_drive_scorer"] = scorer
    return scorer

"""The query fast path of phase-encoder maps: what a fitted model precomputes to answer.

A :class:`ServingPlan` holds, per digit classifier, its selected columns, its weights as one
contiguous float32 block and its biases, and per chunk the periods or the label table.
A batch of queries is answered with one product per (consulted chunk, digit), one padded
log-softmax over every (query, chunk) pair and the exact decoder of
:mod:`service.encoding.exact_decode`, with no Python loop over queries or beams.

**Precision.** ``localize`` multiplies in float32 (half the memory traffic of float64, and
the stored float32 weights are used in place) and *certifies* each answer against the
float64 computation: every score carries a rigorous bound of its float32 error
(``(d'+3)·u·‖w‖·‖z‖`` per class, doubled by the log-softmax), and a query whose winner does
not beat every other candidate by more than the two bounds — or whose set of top chunks
could change within them — is recomputed in float64. So the index and chunk are those of the
exact float64 decode; the confidence agrees to float32 rounding. ``precision="float64"``
computes everything in float64 (the reference; ``frame_log_scores`` always does).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

from service.encoding.base import Localization
from service.encoding.exact_decode import (
    FreeDecode,
    constrained_decode,
    frame_scores_mixed_radix,
    frame_scores_residue,
    frame_scores_table,
    free_decode,
    table_decode,
)
from service.encoding.inverted_file import InvertedFile, Search
from service.encoding.ivf_scan import ListOrder
from service.encoding.ivf_scan import search as ivf_search
from service.encoding.phases import index_to_labels
from service.encoding.residue_decode import residue_decode
from service.encoding.serving_blocks import DigitBlock, PhaseBlock
from service.encoding.single_query import SingleQueryPath

Precision = Literal["float32", "float64"]
_SLACK = 1e-12  # relative slack for float64 rounding of the reference itself
_F32_MAX = float(np.finfo(np.float32).max)
_BLOCK_SCORES = 1 << 22  # (query, chunk, digit, class) scores decoded at once: 32 MB float64


@dataclass(frozen=True)
class Decoded:
    index: np.ndarray  # (n,) int64 global frame index
    chunk: np.ndarray  # (n,) int64
    log_score: np.ndarray  # (n,) float64
    rescored: np.ndarray  # (n,) bool: recomputed in float64 (float32 answer not certain)


class ServingPlan:
    """Precomputed serving state of a :class:`PhaseEncoder` or :class:`ChunkedPlaceEncoder`."""

    def __init__(self, model: Any) -> None:
        encoders = getattr(model, "chunk_encoders_", None)
        if encoders is None:  # one phase encoder, no chunk classifier
            self.phases = (PhaseBlock.of(model),)
            self.bounds = np.array([0, int(model.n_frames_)], dtype=np.int64)
            self.chunk: DigitBlock | None = None
            self.top = 1
        else:
            self.phases = tuple(PhaseBlock.of(enc) for enc in encoders)
            self.bounds = np.asarray(model.chunk_bounds_, dtype=np.int64)
            self.chunk = DigitBlock.of(model.chunk_classifier_)
            self.top = min(int(model.top_chunks), len(self.phases))
        front = getattr(model, "normalizer_", None)
        # A projected front-end is applied in float64 (and rounded for float32 products);
        # a bare normaliser has the fused float32 path of normalise().
        self.projected = front is not None and getattr(front, "projection", None) is not None
        self.front = front
        norm = getattr(front, "normalizer", front)
        self.normalizer = norm
        self.mean = None if norm is None else norm.mean.astype(np.float64)
        self.scale = None if norm is None else norm.scale.astype(np.float64)
        self.n_frames = int(self.bounds[-1])
        self.width = max(p.width for p in self.phases)
        self.k = max(len(p.digits) for p in self.phases)
        self._place = np.zeros((len(self.phases), self.k), dtype=np.int64)
        self._last = np.zeros((len(self.phases), self.k), dtype=np.int64)
        for c, p in enumerate(self.phases):
            self._place[c, : len(p.digits)] = 0 if p.tabled else p.place
            self._last[c, : len(p.digits)] = p.last
        self._sizes = np.diff(self.bounds)
        self._error = np.array([p.error for p in self.phases])
        self._digit_error = np.zeros((len(self.phases), self.k))
        for c, p in enumerate(self.phases):
            self._digit_error[c, : len(p.digits)] = [d.error for d in p.digits]
        self._chunk_error = 0.0 if self.chunk is None else 2.0 * self.chunk.error
        self._tables = any(p.tabled or len(p.digits) != self.k for p in self.phases)
        self._single = SingleQueryPath.of(self)
        ivf = getattr(model, "ivf_", None)  # one class per frame only (one phase, one digit)
        one_class = self.chunk is None and len(self.phases[0].digits) == 1
        self.ivf: InvertedFile | None = ivf if one_class else None
        #: the digit's scales and biases in list order, read by a batch's scan of the lists
        self._by_list = None
        if self.ivf is not None and not self.ivf.probes_everything:
            self._by_list = ListOrder.of(self.ivf, self.phases[0].digits[0])

    # -- helpers --------------------------------------------------------------------
    def normalise(self, Q: np.ndarray, dtype: type = np.float64) -> np.ndarray:
        """Z-scores exactly as the model's normaliser computes them, with its refusal of values
        that would overflow once normalised (``dtype`` float32: the float64 values rounded).
        With a projection: the front-end's float64 rows, rounded for ``float32``."""
        if self.projected:
            return self.front.transform(Q).astype(dtype, copy=False)  # type: ignore[no-any-return]
        if self.normalizer is None:
            return Q.astype(dtype, copy=False)
        if dtype is np.float64:
            return self.normalizer.transform(Q)  # type: ignore[no-any-return]
        out = np.empty(Q.shape, dtype=dtype)
        with np.errstate(over="ignore", invalid="ignore"):
            np.divide(np.subtract(Q, self.mean), self.scale, out=out)
        limit = _F32_MAX / max(1, Q.shape[-1])
        if out.size and not (-limit <= out.min() and out.max() <= limit):
            self.normalizer.transform(Q)  # raises the normaliser's own error for the value
        return out

    def _pairs(
        self, Z: np.ndarray, precision: Precision, zerr: np.ndarray | None
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Candidate chunks ``(n, m)`` (best first), their log-probabilities, and whether
        the set of top chunks is certain under the float32 error (always for float64)."""
        n = Z.shape[0]
        certain = np.ones(n, bool)
        if self.chunk is None:
            return np.zeros((n, 1), np.int64), np.zeros((n, 1)), certain
        s = self.chunk.raw(Z, precision)
        order = (-s).argsort(axis=1, kind="stable")
        rows = np.arange(n)[:, None]
        top = order[:, : self.top]
        tmp = s - s[rows, order[:, :1]]
        top_lp = tmp[rows, top] - np.log(np.add.reduce(np.exp(tmp), axis=1, keepdims=True))
        if zerr is not None and self.top < len(self.phases):
            gap = s[rows, top[:, -1:]] - s[rows, order[:, self.top : self.top + 1]]
            certain = gap[:, 0] > 2.0 * self.chunk.error * zerr  # two scores' errors
        return top, top_lp, certain

    def _raw_scores(self, Z: np.ndarray, q: np.ndarray, pc: np.ndarray,
                    precision: Precision) -> np.ndarray:  # fmt: skip
        """``(P, k, width)`` scores of the pairs (sorted by chunk), ``−inf`` padding."""
        S = np.full((q.shape[0], self.k, self.width), -np.inf)
        cuts = (np.nonzero(pc[1:] != pc[:-1])[0] + 1).tolist()
        for s, e in zip([0, *cuts], [*cuts, q.shape[0]], strict=True):
            Zc = Z.take(q[s:e], axis=0)
            for j, dg in enumerate(self.phases[int(pc[s])].digits):
                dg.raw(Zc, precision, out=S[s:e, j, : dg.n_classes])
        return S

    # -- localize -------------------------------------------------------------------
    def decode(self, Q: np.ndarray, precision: Precision = "float32",
               search: Search | None = None) -> Decoded:  # fmt: skip
        """Exact decode of validated float64 queries ``(n, d)`` (one query: its own path), in
        row blocks whose score arrays stay within :data:`_BLOCK_SCORES` entries (a model with
        one class per frame has ``N`` scores per query). A model with an inverted file answers
        float32 queries through it unless ``search="flat"`` asks for the exact scan or it probes
        every list (the flat scan's answers, faster)."""
        ivf = None if self.ivf is None or self.ivf.probes_everything else self.ivf
        if ivf is not None and precision == "float32" and search != "flat":
            dg = self.phases[0].digits[0]
            Zc = np.ascontiguousarray(self.normalise(Q, np.float32).take(dg.columns, axis=1))
            index, log_score = ivf_search(ivf, dg, Zc, order=self._by_list)
            n = Q.shape[0]
            return Decoded(index, np.zeros(n, np.int64), log_score, np.zeros(n, bool))
        rows = max(1, _BLOCK_SCORES // max(1, self.top * self.k * self.width))
        if Q.shape[0] > rows:
            parts = [self._decode_block(Q[s : s + rows], precision)
                     for s in range(0, Q.shape[0], rows)]  # fmt: skip
            return Decoded(*(np.concatenate([getattr(p, f) for p in parts])
                             for f in ("index", "chunk", "log_score", "rescored")))  # fmt: skip
        return self._decode_block(Q, precision)

    def _decode_block(self, Q: np.ndarray, precision: Precision) -> Decoded:
        if precision == "float32" and Q.shape[0] == 1 and self._single is not None:
            one = self._single.decode(self, Q)
            if one is not None:
                return Decoded(*one)
        if precision == "float64":
            index, chunk, score, _ = self._decode(self.normalise(Q), "float64", None)
            return Decoded(index, chunk, score, np.zeros(Q.shape[0], bool))
        Z32 = self.normalise(Q, np.float32)
        zerr = 1.001 * np.sqrt(np.einsum("ij,ij->i", Z32, Z32))  # ‖z‖ (float32 sums: ≤ d·u off)
        index, chunk, score, certain = self._decode(Z32, "float32", zerr)
        if not certain.all():
            redo = np.nonzero(~certain)[0]
            i64, c64, s64, _ = self._decode(self.normalise(Q[redo]), "float64", None)
            index[redo], chunk[redo], score[redo] = i64, c64, s64
        return Decoded(index, chunk, score, ~certain)

    def _decode(
        self, Z: np.ndarray, precision: Precision, zerr: np.ndarray | None
    ) -> tuple[np.ndarray, ...]:
        """Index, chunk, score and certainty; ``zerr`` (float32 only) scales the bounds."""
        n = Z.shape[0]
        top, top_lp, certain = self._pairs(Z, precision, zerr)
        m = top.shape[1]
        flat = top.ravel()
        order = flat.argsort(kind="stable")  # pairs grouped by chunk
        q, pc = order // m, flat[order]
        S = self._raw_scores(Z, q, pc, precision)
        free = free_decode(S, padded=self._tables)
        local = np.add.reduce(free.digits * self._place[pc], axis=1)
        best = free.best
        valid = local < self._sizes[pc]
        stable = None
        if zerr is not None:  # a digit's argmax holds if its gap beats two class errors
            stable = (free.gaps > 2.0 * self._digit_error[pc] * zerr[q][:, None]).all(axis=1)
        if self._tables:
            self._decode_tables(S, free, pc, q, zerr, local, valid, stable)
        if zerr is None and not valid.all():
            bad = np.nonzero(~valid)[0]
            digits, score = constrained_decode(free.log_probs(S, bad), free.subset(bad),
                                               self._last[pc[bad]])  # fmt: skip
            local[bad] = np.add.reduce(digits * self._place[pc[bad]], axis=1)
            best[bad] = score
            valid[bad] = True
        back = np.empty_like(order)
        back[order] = np.arange(order.size)
        back = back.reshape(n, m)  # (query, rank) → pair
        total = best[back] + top_lp
        win = total.argmax(axis=1)  # the first best rank on ties
        rows = np.arange(n)
        pick = back[rows, win]
        chunk = top[rows, win]
        index = local[pick] + self.bounds[chunk]
        score = total[rows, win]
        if zerr is not None:
            assert stable is not None
            ok = certain & valid[pick] & stable[pick]
            if m > 1:  # the winner must beat every other chunk's upper bound by both errors
                err = ((self._error[pc] + self._chunk_error) * zerr[q])[back]
                total[rows, win] = -np.inf
                margin = score[:, None] - total - err - err[rows, win][:, None]
                ok &= margin.min(axis=1) > _SLACK * (1.0 + np.abs(score))
            certain = ok
        return index, chunk, score, certain

    def _decode_tables(self, S: np.ndarray, free: FreeDecode, pc: np.ndarray, q: np.ndarray,
                       zerr: np.ndarray | None, local: np.ndarray, valid: np.ndarray,
                       stable: np.ndarray | None) -> None:  # fmt: skip
        """Pairs whose chunk has a label table (or fewer digits): enumerate its frames."""
        for c, phase in enumerate(self.phases):
            if not phase.tabled and len(phase.digits) == self.k:
                continue
            rows = np.flatnonzero(pc == c)
            if rows.size == 0:
                continue
            margin = None  # the stability test below, as the residue decode needs it
            if stable is not None and zerr is not None:
                margin = 2.0 * self._digit_error[c].sum() * zerr[q[rows]]
            lp = free.log_probs(S, rows)
            if phase.residue:
                idx, b, second = residue_decode(lp, phase.periods, phase.n_frames, margin)
            else:
                labels = phase.labels
                if labels is None:
                    labels = index_to_labels(np.arange(phase.n_frames), phase.periods)
                idx, b, second = table_decode(lp, labels)
            local[rows], free.best[rows], valid[rows] = idx, b, True
            if margin is not None and stable is not None:  # frames differ by Σ_j Δs_j at most
                stable[rows] = b - second > margin

    def localize(self, Q: np.ndarray, search: Search | None = None) -> Localization:
        """:meth:`decode` as the estimators' :class:`Localization`."""
        d = self.decode(Q, search=search)
        return Localization(d.index, np.exp(d.log_score), d.chunk, d.log_score)

    # -- frame scores -----------------------------------------------------------------
    def frame_log_scores(self, Q: np.ndarray) -> np.ndarray:
        """``(n, N)`` float64 log-probability of every frame (``−inf`` outside the top
        chunks of each query), as the stored model's float64 arithmetic computes them."""
        Z = self.normalise(Q)
        n = Z.shape[0]
        top, top_lp, _ = self._pairs(Z, "float64", None)
        if self.chunk is None:
            return self._phase_scores(0, Z)
        out = np.full((n, self.n_frames), -np.inf)
        for c in np.unique(top).tolist():
            hit = top == c
            rows = np.flatnonzero(hit.any(axis=1))
            clp = top_lp[hit][:, None]  # one entry per row: a chunk appears once in a top set
            s, e = int(self.bounds[c]), int(self.bounds[c + 1])
            out[rows, s:e] = self._phase_scores(c, Z[rows]) + clp
        return out

    def _phase_scores(self, c: int, Z: np.ndarray) -> np.ndarray:
        phase = self.phases[c]
        lp = np.full((Z.shape[0], len(phase.digits), phase.width), -np.inf)
        for j, dg in enumerate(phase.digits):
            lp[:, j, : dg.n_classes] = dg.log_probs64(Z)
        if phase.residue:
            return frame_scores_residue(lp, phase.periods, phase.n_frames)
        if phase.labels is None:
            return frame_scores_mixed_radix(lp, phase.periods, phase.n_frames)
        return frame_scores_table(lp, phase.labels)



def plan_for(model: Any) -> ServingPlan:
    """The model's serving plan, built on first use and kept until the model is refitted."""
    plan = model.__dict__.get("_serving_plan")
    if plan is None:
        plan = model.__dict__["_serving_plan"] = ServingPlan(model)
    return plan  # type: ignore[no-any-return]

"""The one-query path of a :class:`~service.encoding.serving_plan.ServingPlan`.

A single query (the stream frame, the REST single request) is the latency case: the batch
path's grouping of (query, chunk) pairs, its padded scatter and its index bookkeeping are
pure overhead for one row. This path computes the same thing with 1-row specialisations:
the z-scores straight into float32, ``‖z‖`` from one dot product, the chunk classifier's
ranking and log-sum-exp on its few scores as Python floats, one product per (consulted chunk,
digit) written into one ``(m, k, τ_max)`` buffer, and the decode's reductions over that
buffer at once (the bias table carries ``−inf`` past each digit's period).

The certificate is the batch path's (the same float32 error bounds, the same margins), so the
answer is that of the exact float64 decode: a query it cannot certify is decoded in float64,
and anything this path does not handle (label tables, digits missing in a chunk, z-scores
near float32 overflow) goes to the batch path. Confidences agree with the batch path's to
float32 rounding. No buffer is shared between calls: a plan serves many threads at once.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from service.encoding.exact_decode import top_two

if TYPE_CHECKING:
    from service.encoding.serving_plan import ServingPlan

#: index, chunk, log-score and "decoded in float64" of the query, each an array of one
Answer = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]

_SLACK = 1e-12  # the batch path's relative slack for float64 rounding of the reference
_ZZ_LIMIT = float(np.finfo(np.float32).max)  # ‖z‖² finite in float32: every |z_i| < 2^64


class SingleQueryPath:
    """Precomputed 1-row layout of a plan (``None`` from :meth:`of` where it does not apply)."""

    def __init__(self, plan: ServingPlan) -> None:
        n_chunks, k, width = len(plan.phases), plan.k, plan.width
        self.bias = np.full((n_chunks, k, width), -np.inf)  # −inf past each digit's period
        beta = np.ones((n_chunks, k, 1))
        self.padded = False
        for c, phase in enumerate(plan.phases):
            for j, dg in enumerate(phase.digits):
                self.bias[c, j, : dg.n_classes] = dg.bias
                beta[c, j, 0] = dg.beta
                self.padded |= dg.n_classes < width
        self.beta = None if (beta == 1.0).all() else beta
        self.digits = [[(dg.columns, dg, dg.n_classes) for dg in phase.digits]
                       for phase in plan.phases]  # fmt: skip
        self.twice_digit_error = 2.0 * plan._digit_error
        self.pair_error = plan._error + plan._chunk_error
        self.fused_z = plan.mean is not None and self._fused_z_is_the_plans(plan)

    def _fused_z_is_the_plans(self, plan: ServingPlan) -> bool:
        """Whether the fused z-scores below are bit for bit the plan's own (a front-end
        beyond mean and scale, e.g. a projection, goes through ``plan.normalise``)."""
        assert plan.mean is not None and plan.scale is not None
        rng = np.random.default_rng(0)
        probe = plan.mean + plan.scale * rng.standard_normal((1, plan.mean.shape[0]))
        try:
            with np.errstate(over="ignore", invalid="ignore"):
                fused = self._z(plan, probe)
            return bool(np.array_equal(fused, plan.normalise(probe, np.float32)[0]))
        except Exception:  # noqa: BLE001 - any doubt: the plan's own normalisation
            return False

    @staticmethod
    def _z(p: ServingPlan, Q: np.ndarray) -> np.ndarray:
        """Float32 z-scores of one row (the caller silences float overflow: it is checked)."""
        z = np.empty(Q.shape[1], dtype=np.float32)
        np.divide(np.subtract(Q[0], p.mean), p.scale, out=z)
        return z

    @classmethod
    def of(cls, plan: ServingPlan) -> SingleQueryPath | None:
        """Mixed-radix chunks with ``k`` digits each (the rest is the batch path's)."""
        if plan._tables or plan.width < 1:
            return None
        return cls(plan)

    def decode(self, p: ServingPlan, Q: np.ndarray) -> Answer | None:
        """Exact decode of one validated float64 query ``(1, d)`` by the plan ``p`` this was
        made of (not kept here: no reference cycle); ``None``: use the batch path."""
        if not self.fused_z:
            z = np.ascontiguousarray(p.normalise(Q, np.float32)[0])
        with np.errstate(over="ignore", invalid="ignore"):
            if self.fused_z:
                z = self._z(p, Q)
            zz = float(np.dot(z, z))
        if not zz < _ZZ_LIMIT:  # large, infinite or NaN z-scores: the batch path's checks
            return None
        zerr = 1.001 * math.sqrt(zz)  # ‖z‖ (float32 sum: ≤ d·u off)
        top, top_lp, certain = self._chunks(p, z, zerr)
        m, k = len(top), p.k
        buf = (np.zeros if self.padded else np.empty)((m, k, p.width), dtype=np.float32)
        for r, c in enumerate(top):
            for j, (columns, dg, n_classes) in enumerate(self.digits[c]):
                if dg.rowscale is None:
                    np.matmul(dg.weight, z.take(columns), out=buf[r, j, :n_classes])
                else:
                    dg.products(z.take(columns)[None, :], out=buf[r, j, None, :n_classes])
        S = buf + self.bias[top]  # float32 products + float64 biases, as the batch path
        if self.beta is not None:
            S *= self.beta[top]
        digits = S.argmax(axis=2)
        best_d, second = top_two(S, digits)
        log_norm = np.log(np.add.reduce(np.exp(S - best_d[:, :, None]), axis=2))
        total = (top_lp - np.add.reduce(log_norm, axis=1)).tolist()
        local = np.add.reduce(digits * p._place[top], axis=1).tolist()
        win = max(range(m), key=total.__getitem__)  # the first best rank on ties
        chunk, score = top[win], total[win]
        ok = certain and local[win] < int(p._sizes[chunk])
        if ok:  # every digit's argmax holds if its gap beats two class errors
            ok = bool(((best_d[win] - second[win]) > self.twice_digit_error[chunk] * zerr).all())
        if ok and m > 1:  # the winner must beat every other chunk's upper bound by both errors
            err = (self.pair_error[top] * zerr).tolist()
            limit = _SLACK * (1.0 + abs(score))
            ok = all(score - total[r] - err[r] - err[win] > limit for r in range(m) if r != win)
        if not ok:  # not certain in float32: the float64 decode answers
            index, chunks, scores, _ = p._decode(p.normalise(Q), "float64", None)
            return index, chunks, scores, np.ones(1, bool)
        index = np.array([local[win] + int(p.bounds[chunk])], dtype=np.int64)
        return index, np.array([chunk], dtype=np.int64), np.array([score]), np.zeros(1, bool)

    def _chunks(self, p: ServingPlan, z: np.ndarray,
                zerr: float) -> tuple[list[int], np.ndarray, bool]:  # fmt: skip
        """Consulted chunks (best first), their log-probabilities, and whether the set of
        top chunks is certain under the float32 error."""
        if p.chunk is None:
            return [0], np.zeros(1), True
        ch = p.chunk
        s = ch.products(z.take(ch.columns)[None, :])[0] + ch.bias
        if ch.beta != 1.0:
            s *= ch.beta
        scores = s.tolist()
        order = sorted(range(len(scores)), key=lambda i: -scores[i])  # stable, as argsort
        top = order[: p.top]
        best = scores[order[0]]
        lse = math.log(math.fsum(math.exp(v - best) for v in scores))
        top_lp = np.array([scores[c] - best - lse for c in top])
        certain = True
        if p.top < len(p.phases):
            certain = scores[top[-1]] - scores[order[p.top]] > 2.0 * ch.error * zerr
        return top, top_lp, certain

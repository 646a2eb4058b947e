"""Scoring the candidates of an inverted file: the best frame and its log-softmax.

A candidate's score is the flat scan's score of that frame, ``β·(s_i·(z·q_i) + b_i)``: the
float32 product of the query with the stored row (int8 ``q_i`` widened to float32, exact),
times the row's float32 scale, plus its bias and times the inverse temperature in float64.
The answer is the best candidate (the lowest frame on ties, as the flat scan) and its
log-softmax over the candidates.

- **One query** scans the candidate rows in blocks of :data:`BLOCK_ROWS`: each block is
  gathered into one small int8 buffer, widened into one float32 buffer and multiplied there,
  so the widened rows stay in the core's cache instead of making an ``(n_candidates, m)``
  float32 copy that goes to memory and back (1.5× faster at 1M frames).
- **A batch** is scanned list by list: each list's rows are gathered and widened once (in
  blocks of :data:`BLOCK_ROWS`, through the same two buffers) for all the queries that probe
  it and multiplied as ``rows @ queries.T``, the ``(rows, queries)`` shape that OpenBLAS
  multiplies 1.7× faster than ``queries @ rows.T`` at ~250 rows and ~10 queries; every
  (query, list) pair keeps its best score, its first best frame and its sum of
  ``exp(S − best)`` (a column sum taken as one product with a vector of ones), written to a
  slice of pair arrays (the pairs are sorted by list), and the pairs of a query are merged at
  the end in one vectorised step. A list scores at most :data:`LIST_SCORES` (frame, query)
  pairs at a time, so a huge list (a model trained with very few lists) stays bounded.
  The rows' scales and biases are read from copies in list order (:class:`ListOrder`, made
  once per served map: 12 bytes a frame), slices instead of two gathers per list (4 % of a
  batch at 1M frames).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from service.encoding.inverted_file import InvertedFile

#: Candidate rows widened and multiplied at a time by the one-query scan (128 KB of float32
#: at 256 components: a block stays in L2).
BLOCK_ROWS = 512
#: (frame, query) scores of one list made at a time by the batch scan (2 MB of float64):
#: far above a default list's (~√N/4 rows × ~n·nprobe/nlist queries), a bound for huge lists.
LIST_SCORES = 1 << 18
_NO_FRAME = np.iinfo(np.int64).max


class Scorer(Protocol):
    """What the search needs of a digit: its stored rows and how they score."""

    weight: np.ndarray  # (N, m) int8 (with ``rowscale``) or float32
    rowscale: np.ndarray | None
    bias: np.ndarray  # (N,) float64
    beta: float


@dataclass(frozen=True)
class ListOrder:
    """A digit's row scales and biases in the order of an inverted file's ``members`` (the
    array itself is kept: a search with lists of other members ignores these copies)."""

    rowscale: np.ndarray | None  # (N,) float32
    bias: np.ndarray  # (N,) float64
    members: np.ndarray = field(repr=False, compare=False)

    @classmethod
    def of(cls, ivf: InvertedFile, dg: Scorer) -> ListOrder:
        scale = None if dg.rowscale is None else np.ascontiguousarray(dg.rowscale[ivf.members])
        return cls(scale, np.ascontiguousarray(dg.bias[ivf.members]), ivf.members)

    @property
    def nbytes(self) -> int:
        return int(self.bias.nbytes + (0 if self.rowscale is None else self.rowscale.nbytes))

    def rows(self, a: int, b: int) -> tuple[np.ndarray | None, np.ndarray]:
        """Scales and biases of the frames ``members[a:b]`` (slices, no copy)."""
        return None if self.rowscale is None else self.rowscale[a:b], self.bias[a:b]


def _gathered(dg: Scorer, ids: np.ndarray) -> tuple[np.ndarray | None, np.ndarray]:
    """Scales and biases of the frames ``ids``, gathered from the digit's own arrays."""
    return None if dg.rowscale is None else dg.rowscale[ids], dg.bias[ids]


def _finish(dg: Scorer, prod: np.ndarray, rowscale: np.ndarray | None,
            bias: np.ndarray) -> np.ndarray:  # fmt: skip
    """Float64 scores from float32 products ``prod`` (``(frames, ...)``: a row per frame,
    scaled in place) and those frames' scales (``None``: unscaled rows) and biases."""
    col = (bias.size,) + (1,) * (prod.ndim - 1)
    if rowscale is not None:
        prod *= rowscale.reshape(col)
    S = prod + bias.reshape(col)
    if dg.beta != 1.0:
        S *= dg.beta
    return S


def batch_entries_per_query(nprobe: int, n_features: int) -> int:
    """8-byte entries one query of a batch holds while the batch is scanned: its (query, list)
    pairs' arrays (at most 16 of ``nprobe`` entries alive at once) and its rows (float64 and
    float32 copies of ``n_features``); a list's scores and the scan's row buffers are bounded
    apart (:data:`LIST_SCORES`, :data:`BLOCK_ROWS`), whatever the batch."""
    return 16 * int(nprobe) + int(n_features)


def _buffers(W: np.ndarray, rows: int) -> tuple[np.ndarray, np.ndarray]:
    """The two cache-sized buffers a scan gathers ``rows`` stored rows into and widens them
    in (one buffer for float32 weights)."""
    gathered = np.empty((rows, W.shape[1]), dtype=W.dtype)
    wide = gathered if W.dtype == np.float32 else np.empty(gathered.shape, dtype=np.float32)
    return gathered, wide


def _products(W: np.ndarray, ids: np.ndarray, z: np.ndarray, gathered: np.ndarray,
              wide: np.ndarray, out: np.ndarray) -> None:  # fmt: skip
    """``out[i] = q_{ids[i]} · z`` in float32 (``z``: ``(m,)`` or ``(m, queries)``), block by
    block of ``len(gathered)`` rows through the buffers of :func:`_buffers`."""
    rows = gathered.shape[0]
    for i in range(0, ids.size, rows):
        j = min(ids.size, i + rows)
        g = gathered[: j - i]
        np.take(W, ids[i:j], axis=0, out=g, mode="clip")  # valid ids: unbuffered
        if wide is not gathered:
            np.copyto(wide[: j - i], g, casting="unsafe")  # int8 → float32 is exact
        np.matmul(wide[: j - i], z, out=out[i:j])


def _one_query_products(dg: Scorer, z: np.ndarray, ids: np.ndarray) -> np.ndarray:
    """Float32 ``z·q_i`` of the rows ``ids``, block by block through two cache-sized buffers."""
    out = np.empty(ids.size, dtype=np.float32)
    _products(dg.weight, ids, z, *_buffers(dg.weight, min(ids.size, BLOCK_ROWS)), out)
    return out


def search(ivf: InvertedFile, dg: Scorer, Zc: np.ndarray, nprobe: int | None = None,
           order: ListOrder | None = None) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """Best frame and its log-softmax over the candidates for every float32 row of ``Zc``
    ``(n, m)`` (a batch reads scales and biases from ``order`` when given: the same
    arithmetic, so the same answers)."""
    lists = ivf.lists(Zc, nprobe)
    if Zc.shape[0] == 1:
        ids = ivf.candidates(lists[0])
        S = _finish(dg, _one_query_products(dg, Zc[0], ids), *_gathered(dg, ids))
        best = float(S.max())
        win = int(ids[S == best].min())  # the lowest frame on ties, as the flat scan
        lse = math.log(float(np.exp(S - best).sum()))
        return np.array([win], dtype=np.int64), np.array([-lse])
    return _batch(ivf, dg, Zc, lists,
                  order if order is not None and order.members is ivf.members else None)


def _batch(ivf: InvertedFile, dg: Scorer, Zc: np.ndarray, lists: np.ndarray,
           by_list: ListOrder | None) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    n, p = lists.shape
    flat = lists.ravel()
    order = np.argsort(flat, kind="stable")
    queries = order // p
    sorted_lists = flat[order]
    pair_best = np.full(order.size, -np.inf)
    pair_arg = np.full(order.size, _NO_FRAME, dtype=np.int64)
    pair_acc = np.zeros(order.size)  # Σ exp(S − pair_best) over the pair's list
    cuts = np.flatnonzero(np.diff(sorted_lists)) + 1
    o, members, W = ivf.offsets, ivf.members, dg.weight
    longest = max(1, int(np.diff(o).max()))
    gathered, wide = _buffers(W, min(BLOCK_ROWS, longest))
    ones = np.ones(longest)  # column sums as one product: NumPy's axis-0 sum is 4× slower
    for s, e in zip([0, *cuts.tolist()], [*cuts.tolist(), order.size], strict=True):
        c = int(sorted_lists[s])
        a, b = int(o[c]), int(o[c + 1])
        if a == b:
            continue
        ids = members[a:b]
        step = max(1, LIST_SCORES // (b - a))
        for qs in range(s, e, step):
            qe = min(e, qs + step)
            zt = np.ascontiguousarray(Zc.take(queries[qs:qe], axis=0).T)  # (m, queries)
            prod = np.empty((b - a, qe - qs), dtype=np.float32)
            _products(W, ids, zt, gathered, wide, prod)
            S = _finish(dg, prod, *(_gathered(dg, ids) if by_list is None else by_list.rows(a, b)))
            top = S.argmax(axis=0)  # the first best: the lowest frame (ascending in a list)
            bm = S[top, np.arange(qe - qs)]
            S -= bm
            pair_best[qs:qe], pair_arg[qs:qe] = bm, ids[top]
            np.matmul(ones[: b - a], np.exp(S, out=S), out=pair_acc[qs:qe])
    back = np.empty_like(order)
    back[order] = np.arange(order.size)
    back = back.reshape(n, p)  # (query, rank) → pair
    best = pair_best[back]
    top = best.max(axis=1)
    arg = np.where(best == top[:, None], pair_arg[back], _NO_FRAME).min(axis=1)
    with np.errstate(invalid="ignore"):  # empty lists: −inf − (−inf)
        acc = np.where(np.isfinite(best), pair_acc[back] * np.exp(best - top[:, None]), 0.0)
    return arg, -np.log(acc.sum(axis=1))

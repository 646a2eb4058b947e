"""Coarse-to-fine search over one prototype per frame: an inverted file (IVF).

A model with one class per frame (the ``robust`` preset: ``k = 1``, a period equal to the
route) answers a query with the best-scoring of its ``N`` stored prototypes. The flat scan
scores all of them; on a long route that is the whole cost of a query. The inverted file
groups the prototypes into ``nlist`` lists by spherical k-means (FAISS, :class:`faiss.Kmeans`);
a query scores the ``nlist`` centroids (FAISS's flat index for a few queries, one matrix
product per block of a larger batch), then only the prototypes of its ``nprobe`` best
lists, with the model's stored int8 weights and its own scale, bias and temperature, so a
candidate's score is the flat scan's score of that frame. The answer is the best
candidate (the lowest frame on ties, as the flat scan); its log-score is the log-softmax
over the candidates, which equals the flat scan's where every list is probed and is an upper
bound of that frame's flat log-softmax otherwise (the frames left out add to its normaliser).

What is stored: the centroids (float32), the frames of every list (int32, ascending within a
list) and the list offsets — three plain arrays in the artifact beside the weights, so
loading rebuilds nothing and no FAISS object is serialised. The weights are not copied:
candidates are gathered from the stored int8 rows and scored by :mod:`service.encoding.ivf_scan`.

``search`` of an encoder: ``flat`` (the exact reference), ``ivf``, or ``auto`` (the inverted
file from :data:`AUTO_MIN_FRAMES` frames on).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np

from service.errors import InvalidParameterError

Search = Literal["flat", "ivf", "auto"]
SEARCH_MODES: tuple[str, ...] = ("flat", "ivf", "auto")
#: ``auto`` uses the inverted file from this many frames on (below, the flat scan costs
#: well under a millisecond and is exact).
AUTO_MIN_FRAMES = 65_536
DEFAULT_NPROBE = 20
#: Prototypes a query's default lists hold at least, on average: below it the scan costs less
#: than the query's fixed costs (front-end, centroid ranking), and probing fewer lists loses
#: precision for little time; 20 lists of a 1M route hold ≈ 5,000, so this floor binds only
#: on shorter routes.
MIN_CANDIDATES = 4_096
_KMEANS_POINTS = 64  # training points per centroid (a sample of a long route)
_KMEANS_ITER = 12
_BLOCK_ROWS = 16_384  # prototypes dequantised / assigned at a time


def check_search(search: str) -> str:
    if search not in SEARCH_MODES:
        raise InvalidParameterError(f"unknown search {search!r}; choose one of {SEARCH_MODES}")
    return search


def uses_ivf(search: str, n_frames: int) -> bool:
    """Whether an encoder with ``search`` over ``n_frames`` prototypes builds an inverted file."""
    return search == "ivf" or (search == "auto" and n_frames >= AUTO_MIN_FRAMES)


def default_nlist(n_frames: int) -> int:
    """``≈ 4√N`` lists (``≈ √N/4`` prototypes each), at least 1 and at most ``N``."""
    return max(1, min(n_frames, round(4.0 * math.sqrt(n_frames))))


def default_nprobe(nlist: int, n_frames: int) -> int:
    """Lists scanned per query: :data:`DEFAULT_NPROBE`, or more where that many lists hold
    fewer than :data:`MIN_CANDIDATES` prototypes on average (all of a short route's).

    On the SYNTHETIC routes of ``gridplace bench scale`` the share of the prototypes that keeps
    the flat scan's precision falls as the lists grow (``√N``): 20 lists were within 0.6 points
    of it at 100,000 frames (1.6 % of the prototypes) and 0.5 at 1,000,000 (0.5 %), on
    validation queries of those routes. Queries in another condition than the map need a far
    larger share: on Nordland (summer map, winter queries, 3,576 frames, 239 lists) staying
    within 0.5 points took 60 % of the prototypes on the validation half (docs/RESULTS.md,
    "Scale"). The floor keeps a query's scan at the work the 1M target is met at, so a route
    too short for its lists to separate places is scanned whole."""
    p = max(DEFAULT_NPROBE, math.ceil(MIN_CANDIDATES * nlist / max(1, n_frames)))
    return max(1, min(nlist, p))


def _dequantised(weight: np.ndarray, scale: np.ndarray | None, s: int, e: int) -> np.ndarray:
    block = np.asarray(weight[s:e], dtype=np.float32)
    return block if scale is None else block * scale[s:e, None]


#: queries from which the lists are ranked by one matrix product (NumPy's BLAS) instead of
#: FAISS's flat index, which scans the centroids query by query up to a few hundred queries
#: (one BLAS thread, 4,000 × 256 centroids, µs a query, FAISS / product: 158–172 / 195–210 at
#: 1 query, 157–161 / 184–186 at 4, 152–160 / 104–105 at 8, 149–155 / 55–60 at 20, 152 / 31 at
#: 256, 72–73 / 36 at 2,000)
GEMM_RANK_ROWS = 8
#: queries ranked per product: at most this many, and at most _RANK_BLOCK_SCORES centroid scores
#: (4 MB of float32 beside their 8 MB of partition indices), so the ranking's memory is bounded
#: whatever the batch (the work budget counts a batch by its scan's entries per query)
_RANK_BLOCK_ROWS = 256
_RANK_BLOCK_SCORES = 1 << 20


@dataclass(frozen=True)
class InvertedFile:
    centroids: np.ndarray  # (nlist, m) float32, unit rows
    members: np.ndarray  # (N,) int32 frames grouped by list, ascending within a list
    offsets: np.ndarray  # (nlist + 1,) int64 start of every list in ``members``
    nprobe: int
    #: FAISS's flat inner-product index over the centroids (built here, never stored): the
    #: ranking of the lists, one SIMD pass and a heap instead of NumPy's partition and sort
    coarse: Any = field(default=None, init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        import faiss

        index = faiss.IndexFlatIP(self.centroids.shape[1])
        index.add(self.centroids)
        object.__setattr__(self, "coarse", index)

    @classmethod
    def fit(cls, weight: np.ndarray, scale: np.ndarray | None, nlist: int | None = None,
            nprobe: int | None = None, seed: int = 0) -> InvertedFile:  # fmt: skip
        """Lists of the rows ``weight`` (``(N, m)``, int8 with per-row ``scale`` or float):
        spherical k-means on at most :data:`_KMEANS_POINTS` rows per list, then every row in
        the list of its nearest centroid (inner product)."""
        import faiss

        n, m = weight.shape
        k = default_nlist(n) if nlist is None else int(nlist)
        if not 1 <= k <= n:
            raise InvalidParameterError(f"nlist must lie in [1, {n}], got {nlist}")
        rng = np.random.default_rng(seed)
        take = np.sort(rng.choice(n, min(n, k * _KMEANS_POINTS), replace=False))
        sample = np.asarray(weight[take], dtype=np.float32)
        if scale is not None:
            sample *= scale[take, None]
        if k == 1:
            centroids = sample.mean(axis=0, keepdims=True)
        else:
            km = faiss.Kmeans(m, k, niter=_KMEANS_ITER, spherical=True, seed=seed,
                              max_points_per_centroid=_KMEANS_POINTS, min_points_per_centroid=1,
                              verbose=False)  # fmt: skip
            km.train(np.ascontiguousarray(sample))
            centroids = km.centroids
        centroids = np.ascontiguousarray(centroids, dtype=np.float32)
        norms = np.linalg.norm(centroids, axis=1, keepdims=True)
        centroids /= np.maximum(norms, 1e-12)
        index = faiss.IndexFlatIP(m)
        index.add(centroids)
        assign = np.empty(n, dtype=np.int64)
        for s in range(0, n, _BLOCK_ROWS):
            e = min(n, s + _BLOCK_ROWS)
            _, nearest = index.search(np.ascontiguousarray(_dequantised(weight, scale, s, e)), 1)
            assign[s:e] = nearest[:, 0]
        members = np.argsort(assign, kind="stable").astype(np.int32)
        offsets = np.zeros(k + 1, dtype=np.int64)
        np.cumsum(np.bincount(assign, minlength=k), out=offsets[1:])
        probe = default_nprobe(k, n) if nprobe is None else int(nprobe)
        return cls(centroids, members, offsets, max(1, min(k, probe)))

    @property
    def nlist(self) -> int:
        return int(self.centroids.shape[0])

    @property
    def probes_everything(self) -> bool:
        """Whether a query scans every list: then the flat scan gives the same answers without
        ranking centroids and gathering rows, and serving uses it."""
        return self.nprobe >= self.nlist

    @property
    def nbytes(self) -> int:
        return int(self.centroids.nbytes + self.members.nbytes + self.offsets.nbytes)

    def most_scored(self, nprobe: int | None = None) -> int:
        """The most rows one query is scored against: every list centroid, then the frames of
        its ``nprobe`` lists, at most those of the ``nprobe`` largest."""
        p = min(self.nlist, self.nprobe if nprobe is None else int(nprobe))
        sizes = np.sort(np.diff(self.offsets))
        return self.nlist + int(sizes[sizes.size - p:].sum())

    def lists(self, Z: np.ndarray, nprobe: int | None = None) -> np.ndarray:
        """``(n, nprobe)`` lists of float32 rows ``Z`` (``(n, m)``), best first: FAISS's flat
        index for fewer than :data:`GEMM_RANK_ROWS` rows, else one matrix product per block of
        rows (lists whose centroids score alike: FAISS's order; in a product's ranking the lower
        list first, and either where they tie for the last of the ``nprobe``)."""
        p = min(self.nlist, self.nprobe if nprobe is None else int(nprobe))
        Z = np.ascontiguousarray(Z, dtype=np.float32)
        if Z.shape[0] < GEMM_RANK_ROWS:
            _, top = self.coarse.search(Z, p)
            return top  # type: ignore[no-any-return]
        out = np.empty((Z.shape[0], p), dtype=np.int64)
        step = max(GEMM_RANK_ROWS, min(_RANK_BLOCK_ROWS, _RANK_BLOCK_SCORES // self.nlist))
        for lo in range(0, Z.shape[0], step):
            S = Z[lo : lo + step] @ self.centroids.T
            top = np.argpartition(S, self.nlist - p, axis=1)[:, self.nlist - p :]
            s = np.take_along_axis(S, top, axis=1)
            out[lo : lo + step] = np.take_along_axis(top, np.lexsort((top, -s), axis=-1), axis=1)
        return out

    def candidates(self, lists: np.ndarray) -> np.ndarray:
        """Frames of the given lists (one query's), concatenated."""
        o = self.offsets
        return np.concatenate([self.members[o[c] : o[c + 1]] for c in lists.tolist()])

    def to_arrays(self, prefix: str) -> dict[str, np.ndarray]:
        return {f"{prefix}.centroids": self.centroids, f"{prefix}.members": self.members,
                f"{prefix}.offsets": self.offsets,
                f"{prefix}.nprobe": np.array([self.nprobe], dtype=np.int64)}  # fmt: skip

    @classmethod
    def from_arrays(cls, arrays: dict[str, np.ndarray], prefix: str,
                    n_frames: int) -> InvertedFile | None:  # fmt: skip
        """The stored inverted file (``None`` when the model stores none), checked against
        the route: every frame in exactly one list."""
        if f"{prefix}.centroids" not in arrays:
            return None
        out = cls(np.ascontiguousarray(arrays[f"{prefix}.centroids"], dtype=np.float32),
                  np.asarray(arrays[f"{prefix}.members"], dtype=np.int32),
                  np.asarray(arrays[f"{prefix}.offsets"], dtype=np.int64),
                  int(arrays[f"{prefix}.nprobe"][0]))  # fmt: skip
        o = out.offsets
        if (o.shape != (out.nlist + 1,) or o[0] != 0 or o[-1] != n_frames
                or (np.diff(o) < 0).any() or out.members.shape != (n_frames,)
                or not 1 <= out.nprobe <= out.nlist):  # fmt: skip
            raise ValueError(f"{prefix}: inverted file does not cover the {n_frames} frames")
        seen = np.zeros(n_frames, dtype=bool)
        seen[out.members] = True
        if not seen.all():
            raise ValueError(f"{prefix}: inverted file misses frames")
        return out


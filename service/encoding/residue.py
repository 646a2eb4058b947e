"""Residue code: frame ``i``'s digit ``j`` is ``i mod τ_j``.

Unlike the mixed-radix digits of :mod:`service.encoding.phases`, every digit cycles along the
whole route, so each class of each digit pools frames from all over the route and the digit
classifiers have far more classes (``Στ ≈ ratio·N``) for the same ``k``. The periods need
not be co-prime: the decoder scores every frame of the route from its label table
(:func:`service.encoding.exact_decode.table_decode`); frames are distinguishable as long as
``lcm(τ) ≥ N``.

Automatic periods (:func:`residue_periods`) are spread apart rather than consecutive: two
digits whose periods nearly agree alias the same far frames (``i + τ_1 ≈ i + τ_2``), and such
a frame collects two digits' votes at once. Among candidate period sets with ``Στ ≈ ratio·N``
the one whose aliases of different digits lie farthest apart is kept.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence

import numpy as np

from service.errors import InvalidParameterError

CODES: tuple[str, ...] = ("mixed_radix", "residue")
_CANDIDATES = 512  # period sets tried by residue_periods (seeded: deterministic)


def residue_labels(n_frames: int, periods: Sequence[int]) -> np.ndarray:
    """``(N, k)`` table of ``i mod τ_j``."""
    return np.arange(int(n_frames), dtype=np.int64)[:, None] % np.asarray(periods, np.int64)[None]


def validate_residue_periods(periods: Sequence[int], n_frames: int) -> tuple[int, ...]:
    """Integers ≥ 2, pairwise distinct, whose least common multiple covers ``n_frames``."""
    out: list[int] = []
    for p in periods:
        if isinstance(p, bool) or int(p) != p or int(p) < 2:
            raise InvalidParameterError(f"every period must be an integer >= 2, got {p!r}")
        out.append(int(p))
    if not out:
        raise InvalidParameterError("periods must name at least one period")
    if len(set(out)) != len(out):
        raise InvalidParameterError(f"residue periods must be pairwise distinct, got {tuple(out)}")
    if math.lcm(*out) < n_frames:
        raise InvalidParameterError(
            f"residue periods {tuple(out)} repeat every lcm = {math.lcm(*out)} frames, fewer "
            f"than the {n_frames} frames of the route", periods=out, n_frames=n_frames,
        )  # fmt: skip
    return tuple(out)


def alias_gap(periods: Sequence[int], n_frames: int) -> int:
    """Smallest distance between multiples of two different periods inside the route (how
    close one digit's alias of a frame comes to another digit's)."""
    best = int(n_frames)
    for a, b in itertools.combinations(periods, 2):
        ma = np.arange(0, n_frames, a)
        mb = np.arange(0, n_frames, b)
        d = np.abs(ma[:, None] - mb[None, :])
        d[0, 0] = n_frames  # the frame itself
        best = min(best, int(d.min()))
    return best


def code_sum(n_frames: int, ratio: float = 1.0, exponent: float = 1.0) -> int:
    """The target ``Στ = ratio·N^exponent`` (at most ``N`` when ``exponent < 1``: a code that
    grows sub-linearly never has more classes than frames)."""
    total = ratio * float(n_frames) ** exponent
    if exponent < 1.0:
        total = min(total, float(n_frames))
    return int(round(total))


def residue_periods(
    n_frames: int, n_patterns: int, ratio: float = 1.0, exponent: float = 1.0
) -> tuple[int, ...]:
    """``n_patterns`` distinct periods with ``Στ ≈ ratio·N^exponent`` (:func:`code_sum`) and
    ``lcm ≥ N`` whose aliases lie farthest apart (:func:`alias_gap`); ties go to the smaller
    sum. Deterministic."""
    if n_frames < 2:
        raise InvalidParameterError(f"a route needs at least 2 frames, got {n_frames}")
    k = int(n_patterns)
    if k < 1:
        raise InvalidParameterError(f"the number of patterns must be >= 1, got {n_patterns}")
    if not ratio > 0:
        raise InvalidParameterError(f"code_ratio must be > 0, got {ratio}")
    max_k = max(1, math.ceil(math.log2(n_frames)))  # the mixed-radix code's bound too
    if k > max_k:
        raise InvalidParameterError(
            f"{k} patterns is too many for {n_frames} frames: at most {max_k} (log2 N) digits",
            n_frames=n_frames, max_patterns=max_k,
        )  # fmt: skip
    if k == 1:
        return (max(2, n_frames),)
    floor = sum(range(2, 2 + k))  # the smallest sum of k distinct periods >= 2
    total = max(floor, code_sum(n_frames, ratio, exponent))
    rng = np.random.default_rng(0)
    best: tuple[int, int, tuple[int, ...]] | None = None
    for t in range(_CANDIDATES):
        if t == 0:  # near-equal periods: the fallback that always exists
            base = max(2, total // k - (k - 1))
            cand = tuple(base + 2 * j for j in range(k))
        else:
            share = rng.dirichlet(np.full(k, 8.0)) * total
            cand = tuple(sorted({max(2, int(round(x))) for x in share}))
        if len(cand) != k or math.lcm(*cand) < n_frames:
            continue
        key = (alias_gap(cand, n_frames), -sum(cand), cand)
        if best is None or key[:2] > best[:2]:
            best = key
    if best is None:  # tiny routes: the smallest distinct periods
        cand = tuple(range(2, 2 + k))
        while math.lcm(*cand) < n_frames:
            cand = tuple(p + 1 for p in cand)
        return cand
    return tuple(sorted(best[2], reverse=True))

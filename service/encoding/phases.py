"""Phase labels: the mixed-radix digits of a frame index.

Frame ``i`` of a route gets digits ``l_1 … l_k`` with periods ``τ_1 … τ_k`` (τ_1 the most
significant digit, all digits 0-based), so encoder 1 sees contiguous blocks of the route and
encoder k sees ``i mod τ_k``. The inverse is ``i = Σ_j l_j · ∏_{m>j} τ_m`` (the paper's
eq. (1) is off by one; this is the correct 0-based form).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from service.errors import InvalidParameterError


def validate_periods(periods: Sequence[int], n_frames: int | None = None) -> tuple[int, ...]:
    """Check that periods are integers ≥ 2 whose product covers ``n_frames``."""
    if len(periods) == 0:
        raise InvalidParameterError("periods must name at least one period")
    out: list[int] = []
    for p in periods:
        if isinstance(p, bool) or int(p) != p:
            raise InvalidParameterError(f"periods must be integers, got {p!r}")
        if int(p) < 2:
            raise InvalidParameterError(f"every period must be >= 2, got {int(p)}")
        out.append(int(p))
    if n_frames is not None and math.prod(out) < n_frames:
        raise InvalidParameterError(
            f"the product of periods {tuple(out)} is {math.prod(out)}, "
            f"smaller than the number of frames {n_frames}",
            periods=out,
            n_frames=n_frames,
        )
    return tuple(out)


def parse_periods(text: str | None, what: str = "periods") -> tuple[int, ...] | None:
    """``"60,60"`` or ``"60x60"`` → ``(60, 60)``; empty → ``None`` (automatic periods)."""
    if not text:
        return None
    try:
        return tuple(int(p) for p in text.replace("x", ",").split(",") if p.strip())
    except ValueError as exc:
        raise InvalidParameterError(
            f"{what} must be integers separated by commas: {text!r}"
        ) from exc


def place_values(periods: Sequence[int]) -> np.ndarray:
    """Weight of each digit: ``∏_{m>j} τ_m`` (the last digit has weight 1)."""
    p = np.asarray(periods, dtype=np.int64)
    vals = np.ones(len(p), dtype=np.int64)
    for j in range(len(p) - 2, -1, -1):
        vals[j] = vals[j + 1] * p[j + 1]
    return vals


def index_to_labels(indices: np.ndarray | Sequence[int], periods: Sequence[int]) -> np.ndarray:
    """Mixed-radix digits of each index, shape ``(n, k)``; τ_1 is column 0."""
    periods = validate_periods(periods)
    idx = np.asarray(indices, dtype=np.int64)
    if idx.ndim != 1:
        raise InvalidParameterError("indices must be one-dimensional")
    if idx.size and (idx.min() < 0 or idx.max() >= math.prod(periods)):
        raise InvalidParameterError(
            f"indices must lie in [0, {math.prod(periods)}) for periods {periods}"
        )
    vals = place_values(periods)
    return (idx[:, None] // vals[None, :]) % np.asarray(periods, dtype=np.int64)[None, :]


def labels_to_index(labels: np.ndarray, periods: Sequence[int]) -> np.ndarray:
    """Inverse of :func:`index_to_labels`: ``i = Σ_j l_j · ∏_{m>j} τ_m``."""
    periods = validate_periods(periods)
    lab = np.asarray(labels, dtype=np.int64)
    if lab.ndim != 2 or lab.shape[1] != len(periods):
        raise InvalidParameterError(
            f"labels must have shape (n, {len(periods)}), got {lab.shape}"
        )
    if lab.size and ((lab < 0).any() or (lab >= np.asarray(periods)[None, :]).any()):
        raise InvalidParameterError("every digit must lie in [0, period)")
    return lab @ place_values(periods)


def auto_periods(n_frames: int, n_patterns: int) -> tuple[int, ...]:
    """Balanced periods for ``n_frames`` with ``n_patterns`` encoders.

    Returns integers ≥ 2 with ``∏τ ≥ N`` and the smallest possible ``Στ`` (the storage
    term), ties broken by the smallest product (fewest unused codes). An optimum always uses
    values from ``{c, c+1}`` for one ``c``: replacing ``(a, b)`` with ``b ≥ a + 2`` by
    ``(a + 1, b − 1)`` keeps the sum and does not lower the product. Larger periods come
    first (most significant digit). Unlike the paper's code, ``N`` need not factorise and
    ``k`` is never silently capped: a ``k`` too large to be useful is an error.
    """
    if n_frames < 2:
        raise InvalidParameterError(f"a route needs at least 2 frames, got {n_frames}")
    if n_patterns < 1:
        raise InvalidParameterError(f"the number of patterns must be >= 1, got {n_patterns}")
    max_k = max(1, math.ceil(math.log2(n_frames)))
    if n_patterns > max_k:
        raise InvalidParameterError(
            f"{n_patterns} patterns is too many for {n_frames} frames: with every period >= 2 "
            f"at most {max_k} patterns carry information",
            n_frames=n_frames,
            max_patterns=max_k,
        )
    k = n_patterns
    base = max(2, int(math.floor(n_frames ** (1.0 / k))) - 1)
    best: tuple[int, int, tuple[int, ...]] | None = None
    for c in range(base, base + 3):
        for m in range(k + 1):  # m periods equal c + 1, the rest c
            prod = (c + 1) ** m * c ** (k - m)
            if prod >= n_frames:
                cand = tuple([c + 1] * m + [c] * (k - m))
                key = (sum(cand), prod, cand)
                if best is None or key[:2] < best[:2]:
                    best = key
                break
    assert best is not None  # c = base + 2 > N^(1/k) always covers N
    return best[2]

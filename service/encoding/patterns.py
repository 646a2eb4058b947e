"""Pattern learning: which descriptor columns carry an encoder's digit.

For a labelling of the frames (an encoder's digit, or the chunk id), every column gets its
between-cluster sum of squares ``a_j = TSS_j − WCSS_j = Σ_c n_c (μ_cj − μ_j)²``, computed in
``O(N·d)`` from group means. Sparse column weights follow Witten & Tibshirani (2010),
Proposition 1: ``w = S(a₊, Δ) / ||S(a₊, Δ)||₂`` with ``Δ = 0`` if that already satisfies
``||w||₁ ≤ γ``, otherwise ``Δ > 0`` found by binary search so that ``||w||₁ = γ``. The top
``d'`` columns by weight (ties by BCSS, then by column index) are kept.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from service.errors import InvalidParameterError


def bcss(X: np.ndarray, labels: np.ndarray, n_classes: int | None = None) -> np.ndarray:
    """Per-column between-cluster sum of squares, shape ``(d,)``.

    Uses group sums only (one pass over ``X``), never pairwise distances.
    """
    X = np.asarray(X, dtype=np.float64)
    labels = np.asarray(labels, dtype=np.int64)
    if X.ndim != 2 or labels.shape != (X.shape[0],):
        raise InvalidParameterError("bcss needs X of shape (n, d) and labels of shape (n,)")
    n_classes = int(labels.max()) + 1 if n_classes is None else n_classes
    counts = np.bincount(labels, minlength=n_classes).astype(np.float64)
    sums = np.zeros((n_classes, X.shape[1]), dtype=np.float64)
    add_group_sums(X, labels, sums)
    return bcss_from_sums(sums, counts, X.shape[0])


def bcss_from_sums(sums: np.ndarray, counts: np.ndarray, n_rows: int) -> np.ndarray:
    """:func:`bcss` from the classes' row sums ``(τ, d)`` and counts ``(τ,)`` of ``n_rows``
    rows (sums that were accumulated block by block over a long route)."""
    grand_mean = sums.sum(axis=0) / n_rows
    present = counts > 0
    means = sums[present] / counts[present, None]
    diff = means - grand_mean[None, :]
    return np.einsum("c,cd,cd->d", counts[present], diff, diff)  # type: ignore[no-any-return]


def add_group_sums(X: np.ndarray, labels: np.ndarray, out: np.ndarray) -> None:
    """Add the row sums per label to ``out`` via a sparse one-hot product (fast for large ``n``)."""
    from scipy import sparse

    onehot = sparse.csr_matrix(
        (np.ones(labels.shape[0]), (labels, np.arange(labels.shape[0]))),
        shape=(out.shape[0], labels.shape[0]),
    )
    out += onehot @ X


def soft_threshold(a: np.ndarray, delta: float) -> np.ndarray:
    """``S(a, Δ) = sign(a) · max(|a| − Δ, 0)``."""
    return np.sign(a) * np.maximum(np.abs(a) - delta, 0.0)


def sparse_weights(scores: np.ndarray, gamma: float, tol: float = 1e-10) -> np.ndarray:
    """Solve ``max wᵀa`` s.t. ``||w||₂ ≤ 1``, ``||w||₁ ≤ γ`` (Witten & Tibshirani, Prop. 1).

    Returns non-negative weights; all zeros when no score is positive.
    """
    if not gamma >= 1.0:
        raise InvalidParameterError(f"gamma must be >= 1 (the L1 bound of a unit vector), got {gamma}")
    a = np.maximum(np.asarray(scores, dtype=np.float64), 0.0)
    top = float(a.max(initial=0.0))
    if top <= 0.0:
        return np.zeros_like(a)
    a = a / top  # scale-free: the top score is 1 and Δ is searched in [0, 1)
    w = _unit(a)
    if w.sum() <= gamma:
        return w
    # Invariant: ||w(lo)||₁ > γ, and ||w(hi)||₁ ≤ γ whenever hi < 1. Every Δ < 1 keeps the
    # top column, so no normalisation below ever divides by zero.
    lo, hi = 0.0, 1.0
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if _unit(soft_threshold(a, mid)).sum() > gamma:
            lo = mid
        else:
            hi = mid
        if hi - lo < tol:
            break
    if hi < 1.0:
        return _unit(soft_threshold(a, hi))
    return _tied_top(a, gamma)


def _unit(s: np.ndarray) -> np.ndarray:
    """``s / ||s||₂`` for a vector with at least one positive entry."""
    return s / np.linalg.norm(s)


def _tied_top(a: np.ndarray, gamma: float) -> np.ndarray:
    """The degenerate case where no threshold Δ < 1 meets the L1 bound.

    It happens when m columns tie (to within the search tolerance) for the top score and
    √m > γ: soft-thresholding shrinks them alike, so ||w||₁ only falls to √m at Δ → 1, where
    every weight vanishes. Unit mass spread evenly over the first ⌊γ²⌋ exact ties (by column
    index) satisfies both bounds and is optimal up to ||w||₁ rounding (√⌊γ²⌋ ≤ γ).
    """
    ties = np.flatnonzero(a == a.max())[: max(1, int(np.floor(gamma**2)))]
    w = np.zeros_like(a)
    w[ties] = 1.0 / np.sqrt(ties.size)
    return w


@dataclass(frozen=True)
class PatternSelection:
    """The outcome of pattern learning for one labelling."""

    columns: np.ndarray  # selected column indices, ascending, shape (d',)
    weights: np.ndarray  # sparse weights of all d columns, shape (d,)
    scores: np.ndarray  # BCSS of all d columns, shape (d,)


def n_selected(n_features: int, rho: float) -> int:
    """``d' = round(ρ·d)``, at least one column."""
    if not 0.0 < rho <= 1.0:
        raise InvalidParameterError(f"rho must lie in (0, 1], got {rho}")
    return max(1, min(n_features, int(round(rho * n_features))))


def learn_pattern(
    X: np.ndarray,
    labels: np.ndarray,
    rho: float,
    gamma: float | None = None,
    n_classes: int | None = None,
) -> PatternSelection:
    """Select the ``d' = round(ρ·d)`` columns that best separate ``labels``."""
    return select_columns(bcss(X, labels, n_classes), rho, gamma)


def select_columns(scores: np.ndarray, rho: float, gamma: float | None = None) -> PatternSelection:
    """Sparse weights from BCSS ``scores`` and the top ``d' = round(ρ·d)`` columns.

    ``gamma=None`` uses ``√d'``: the L1 norm of a unit vector spread evenly over ``d'``
    columns, so the sparse weights concentrate on about the number of columns kept.
    """
    d = scores.shape[0]
    k = n_selected(d, rho)
    gamma_eff = float(np.sqrt(k)) if gamma is None else float(gamma)
    weights = sparse_weights(scores, gamma_eff)
    # Stable ranking: weight desc, then BCSS desc, then column index asc.
    order = np.lexsort((np.arange(d), -scores, -weights))
    columns = np.sort(order[:k])
    return PatternSelection(columns=columns, weights=weights, scores=scores)

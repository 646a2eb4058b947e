"""Route lengths for the scaling sweeps."""

from __future__ import annotations

import numpy as np


def geometric_sizes(n_min: int, n_max: int, n_points: int) -> list[int]:
    """About ``n_points`` route lengths from ``n_min`` to ``n_max`` evenly spaced in log scale
    (always including ``n_max``; duplicates after rounding removed)."""
    n_min = max(2, min(n_min, n_max))
    if n_points <= 1 or n_min == n_max:
        return [n_max]
    sizes = np.unique(np.round(np.geomspace(n_min, n_max, n_points)).astype(int))
    return [int(s) for s in sizes]

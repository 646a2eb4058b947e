"""SYNTHETIC routes for tests, demos and the harness when no real data is at hand.

Everything produced here is synthetic and says so: frames come from a slowly varying random
process (Gaussian-smoothed noise along the route, so neighbouring frames look alike, as
neighbouring camera frames do), and queries are the same frames with fresh noise, standing in
for a second traversal under other conditions.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.ndimage import gaussian_filter1d

SYNTHETIC_LABEL = "SYNTHETIC (smooth random-process route; not real imagery)"


@dataclass(frozen=True)
class SyntheticRoute:
    reference: np.ndarray  # (n, d) float32, rows in route order
    query: np.ndarray  # (n, d) float32, query i ↔ reference i
    label: str = SYNTHETIC_LABEL


def smooth_route(
    n_frames: int,
    n_features: int,
    smoothness: float = 3.0,
    query_noise: float = 0.3,
    frame_noise: float = 0.2,
    seed: int = 0,
) -> SyntheticRoute:
    """A SYNTHETIC route of ``n_frames`` descriptors and noisy queries of the same places.

    ``smoothness`` is the correlation length along the route in frames; ``frame_noise`` adds
    a per-frame component so that no two frames are identical; ``query_noise`` is the
    standard deviation of the query perturbation relative to unit-variance columns.
    """
    rng = np.random.default_rng(seed)
    base = gaussian_filter1d(rng.standard_normal((n_frames, n_features)), smoothness, axis=0)
    base /= base.std(axis=0, keepdims=True) + 1e-12
    ref = base + frame_noise * rng.standard_normal(base.shape)
    query = ref + query_noise * rng.standard_normal(base.shape)
    return SyntheticRoute(ref.astype(np.float32), query.astype(np.float32))

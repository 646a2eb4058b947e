"""SYNTHETIC routes for tests, demos and the harness when no real data is at hand.

Everything produced here is synthetic and says so: frames come from a slowly varying random
process (Gaussian-smoothed noise along the route, so neighbouring frames look alike, as
neighbouring camera frames do), and queries are the same frames with fresh noise, standing in
for a second traversal under other conditions.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.ndimage import correlate1d, gaussian_filter1d

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


_BLOCK = 32768  # rows per generator seed: the route depends on it, so it is fixed


def _kernel(smoothness: float) -> np.ndarray:
    """The Gaussian kernel of ``gaussian_filter1d`` (truncated at 4σ), normalised to sum 1."""
    radius = int(4.0 * smoothness + 0.5)
    x = np.arange(-radius, radius + 1, dtype=np.float64)
    k = np.exp(-0.5 * (x / smoothness) ** 2)
    return k / k.sum()


def write_route(
    path: str | Path,
    n_frames: int,
    n_features: int,
    smoothness: float = 3.0,
    frame_noise: float = 0.2,
    region_length: int = 0,
    seed: int = 0,
) -> np.ndarray:
    """Write a SYNTHETIC route's reference descriptors to a float32 ``.npy`` file, one block of
    rows at a time, and return it memory-mapped read-only (never ``N×d`` float64 in memory).

    The same process as :func:`smooth_route` (Gaussian-smoothed noise along the route plus
    per-frame noise), but each block's noise comes from its own seeded generator, so any N can
    be produced in bounded memory; the smoothed part is scaled by its exact standard deviation
    (``‖kernel‖₂``; frames within 4σ of either end see zeros beyond the route). With
    ``region_length > 0`` a regional component (unit-variance anchors every ``region_length``
    frames, interpolated) gives distant parts of the route systematically different scenery,
    which a chunk classifier can learn.
    """
    path = Path(path)
    block = _BLOCK
    k = _kernel(smoothness)
    radius = (k.size - 1) // 2
    std = float(np.sqrt(np.sum(k**2)))
    out = np.lib.format.open_memmap(path, mode="w+", dtype=np.float32, shape=(n_frames, n_features))
    anchors = None
    if region_length > 0:
        anchors = np.random.default_rng([seed, 2]).standard_normal(
            (n_frames // region_length + 2, n_features)
        )

    def noise(t: int) -> np.ndarray:
        rows = min(block, n_frames - t * block)
        if t < 0 or rows <= 0:
            return np.zeros((block if t < 0 else 0, n_features), np.float32)
        return np.random.default_rng([seed, 0, t]).standard_normal((rows, n_features), np.float32)

    for t in range(-(-n_frames // block)):
        s, e = t * block, min(n_frames, (t + 1) * block)
        ext = np.concatenate([noise(t - 1)[-radius:], noise(t), noise(t + 1)[:radius]])
        pad_lo = radius - min(radius, s)  # rows before the route are zeros
        pad_hi = radius - min(radius, n_frames - e)
        ext = np.concatenate([np.zeros((pad_lo, n_features), np.float32), ext[radius - min(radius, s):],
                              np.zeros((pad_hi, n_features), np.float32)]) if (pad_lo or pad_hi) else ext  # fmt: skip
        smooth = correlate1d(ext, k, axis=0, mode="constant")[radius : ext.shape[0] - radius]
        rows = smooth / std + frame_noise * np.random.default_rng([seed, 1, t]).standard_normal(
            smooth.shape, np.float32
        )
        if anchors is not None:
            pos = np.arange(s, e) / region_length
            i0 = pos.astype(np.int64)
            w = (pos - i0)[:, None]
            rows += (anchors[i0] * (1.0 - w) + anchors[i0 + 1] * w) / np.sqrt(2.0 / 3.0)
        out[s:e] = rows
    out.flush()
    del out
    return np.load(path, mmap_mode="r")


def route_queries(
    reference: np.ndarray, rows: np.ndarray, query_noise: float = 0.3, seed: int = 0
) -> np.ndarray:
    """SYNTHETIC queries of the frames ``rows``: the reference plus fresh noise (float32)."""
    rng = np.random.default_rng([seed, 3])
    ref = np.asarray(reference[np.asarray(rows)], dtype=np.float64)
    return (ref + query_noise * rng.standard_normal(ref.shape)).astype(np.float32)

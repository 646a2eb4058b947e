"""Where a vehicle tracker's windows lie on the route (:mod:`service.encoding.tracking`): the
frames they cover, the frames they leave outside, and the places a posterior puts windows at.

A window is ``width`` consecutive frames from its first frame ``lo``; windows may overlap.
"""

from __future__ import annotations

import numpy as np


def covered(lo: np.ndarray, width: int, n_frames: int) -> np.ndarray:
    """Mask ``(n_frames,)`` of the frames inside any window."""
    mask = np.zeros(n_frames, dtype=bool)
    for first in lo.tolist():
        mask[first : first + width] = True
    return mask


def frames_outside(lo: np.ndarray, width: int, n_frames: int) -> int:
    """Frames outside every window (the union of the windows' intervals, ``O(B log B)``)."""
    inside, end = 0, -1
    for first in sorted(lo.tolist()):
        hi = first + width
        if hi > end:
            inside += hi - max(first, end)
            end = hi
    return n_frames - inside


def best_places(posterior: np.ndarray, width: int, most: int) -> np.ndarray:
    """First frames of up to ``most`` windows at the posterior's best places, the best first:
    each centred on the best frame of its block of ``width`` frames, blocks by their best
    frame's mass, a place inside an earlier window skipped; ``O(N)``."""
    n = posterior.size
    padded = np.zeros(-(-n // width) * width)
    padded[:n] = posterior
    blocks = padded.reshape(-1, width)
    peak = blocks.argmax(axis=1) + width * np.arange(blocks.shape[0])
    k = min(peak.size, 2 * most)
    top = peak[np.argpartition(-padded[peak], k - 1)[:k]]
    radius = width // 2
    los: list[int] = []
    for c in top[np.argsort(-padded[top], kind="stable")].tolist():
        if len(los) == most:
            break
        if not any(lo <= c < lo + width for lo in los):
            los.append(int(np.clip(c - radius, 0, n - width)))
    return np.array(los, dtype=np.int64)

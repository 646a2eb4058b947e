"""Where a vehicle tracker's windows lie on the route (:mod:`service.encoding.tracking`): the
frames they cover, the frames they leave outside, the places a posterior puts windows at, and
how a window follows its belief.

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


def recentre(P: np.ndarray, lo: np.ndarray, outside: float, radius: int, n_frames: int) -> float:
    """Move each window of the states ``P`` ``(S, B, W)`` (first frames ``lo``, updated in
    place) whose peak drifted more than ``radius // 2`` from its centre; the mass a move drops
    joins the outside, the frames it newly covers take the outside's density. Returns the
    outside mass."""
    S, B, W = P.shape
    peaks = P.sum(axis=0).argmax(axis=1)
    for b in range(B):
        new = int(np.clip(lo[b] + int(peaks[b]) - radius, 0, n_frames - W))
        delta = new - int(lo[b])
        if abs(delta) <= radius // 2:
            continue
        density = outside / (S * max(1, frames_outside(lo, W, n_frames)))
        win = P[:, b]
        moved = np.full_like(win, density)
        if abs(delta) < W:
            if delta > 0:
                moved[:, : W - delta] = win[:, delta:]
                gone = float(win[:, :delta].sum(dtype=np.float64))
            else:
                moved[:, -delta:] = win[:, : W + delta]
                gone = float(win[:, W + delta :].sum(dtype=np.float64))
            fresh = abs(delta)
        else:
            gone, fresh = float(win.sum(dtype=np.float64)), W
        outside = max(0.0, outside + gone - density * S * fresh)
        P[:, b] = moved
        lo[b] = new
    return outside


def windows_to_keep(mass: np.ndarray, age: np.ndarray, level: float, probation: int,
                    most: int) -> np.ndarray:  # fmt: skip
    """Mask of the windows to keep: the best, those holding more than ``level`` and those
    younger than ``probation`` frames — at most ``most`` of them, the heaviest."""
    keep = (mass > level) | (age < probation)
    keep[int(mass.argmax())] = True
    if keep.sum() > most:
        keep[:] = False
        keep[np.argsort(-mass)[:most]] = True
    return keep

"""Weight-free descriptors for small grayscale frames (SeqSLAM-style patch normalisation)."""

from __future__ import annotations

import numpy as np

from service.errors import InvalidParameterError


def patch_normalize(images: np.ndarray, patch: int = 8, eps: float = 1e-6) -> np.ndarray:
    """Zero-mean, unit-variance pixels within each ``patch×patch`` tile, flattened per frame.

    ``images`` is ``(n, h, w)``; ``h`` and ``w`` must be multiples of ``patch``. A flat tile
    (black frames, tunnels) becomes zeros instead of dividing by ~0.
    """
    imgs = np.asarray(images, dtype=np.float32)
    if imgs.ndim != 3:
        raise InvalidParameterError(f"images must be (n, h, w), got shape {imgs.shape}")
    n, h, w = imgs.shape
    if h % patch or w % patch:
        raise InvalidParameterError(f"image size {h}x{w} is not a multiple of patch {patch}")
    tiles = imgs.reshape(n, h // patch, patch, w // patch, patch)
    mean = tiles.mean(axis=(2, 4), keepdims=True)
    std = tiles.std(axis=(2, 4), keepdims=True)
    out = np.where(std > eps, (tiles - mean) / np.maximum(std, eps), 0.0)
    return out.reshape(n, h * w).astype(np.float32)

"""Deterministic test images for the imaging tests (a uniquely named module)."""

from __future__ import annotations

import io

import numpy as np
from PIL import Image


def scene(seed: int, size: tuple[int, int] = (64, 32)) -> Image.Image:
    """A SYNTHETIC grayscale 'scene': smooth structure (a horizon, bars) plus seeded texture."""
    w, h = size
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    rng = np.random.default_rng(seed)
    phase = rng.uniform(0, 2 * np.pi, 3)
    sky = 60.0 + 120.0 * (yy < h * (0.35 + 0.1 * np.sin(xx / w * 2 * np.pi + phase[0])))
    bars = 50.0 * (np.sin(xx / w * 6 * np.pi + phase[1]) > 0.6)
    texture = 25.0 * rng.standard_normal((h, w))
    ripple = 20.0 * np.cos(yy / h * 4 * np.pi + phase[2])
    return Image.fromarray(np.clip(sky + bars + texture + ripple, 0, 255).astype(np.uint8))


def png(img: Image.Image) -> bytes:
    buf = io.BytesIO()
    img.save(buf, format="PNG")
    return buf.getvalue()

"""Helpers shared by the API tests (a uniquely named module: every test dir has a conftest)."""

from __future__ import annotations

import io

import numpy as np
from api_fakes import FakeRegistry
from PIL import Image

TOKEN = "s3cret-admin-token"


def npy_bytes(X: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.save(buf, X, allow_pickle=False)
    return buf.getvalue()


def png_bytes(seed: int, size: tuple[int, int] = (64, 32)) -> bytes:
    rng = np.random.default_rng(seed)
    img = Image.fromarray(rng.integers(0, 255, (size[1], size[0]), dtype=np.uint8))
    buf = io.BytesIO()
    img.save(buf, format="PNG")
    return buf.getvalue()


def expected_index(registry: FakeRegistry, name: str, version: int, X: np.ndarray) -> list[int]:
    """The in-process model's answers: what REST must return."""
    return registry.load_model(name, version).localize(np.atleast_2d(X)).index.tolist()  # type: ignore[no-any-return]

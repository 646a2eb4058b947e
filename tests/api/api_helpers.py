"""Helpers shared by the API tests (a uniquely named module: every test dir has a conftest)."""

from __future__ import annotations

import io
import zipfile
from typing import Any

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


def upload_image_map(client: Any, auth: dict[str, str], n_frames: int = 30) -> None:
    """Map 'imgs': ``n_frames`` random PNG frames (``png_bytes(i)``) trained with ridge on
    32×16 patch-normalised descriptors, and served."""
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as zf:
        for i in range(n_frames):
            zf.writestr(f"frames/img-{i:03d}.png", png_bytes(i))
    r = client.post("/v1/maps/imgs/routes", headers=auth, files={"file": ("route.zip", buf.getvalue())},
                    data={"trainer": "ridge", "extractor": "patchnorm", "width": "32", "height": "16",
                          "patch": "8"})  # fmt: skip
    assert r.status_code == 202, r.text
    client.app.state.context.store.refresh()

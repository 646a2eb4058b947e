"""Constants and helpers of the client tests (a uniquely named module, beside conftest.py)."""

from __future__ import annotations

import io
import time
import zipfile

import numpy as np
from PIL import Image

from service.client import GridplaceClient, TrainingOptions

TOKEN = "client-tests-admin-token"
N, D = 300, 64
ENV = {"GRIDPLACE_ADMIN_TOKEN": TOKEN, "GRIDPLACE_MAX_UPLOAD_MB": "1",
       "GRIDPLACE_RELOAD_INTERVAL_S": "0.1", "GRIDPLACE_TRAIN_WORKERS": "1"}  # fmt: skip
IMAGE_OPTIONS = TrainingOptions(extractor="patchnorm", width=32, height=16, patch=8)


def png(seed: int) -> bytes:
    """A random 32×16 grey PNG (SYNTHETIC camera frame)."""
    rng = np.random.default_rng(seed)
    buf = io.BytesIO()
    Image.fromarray(rng.integers(0, 255, (16, 32), dtype=np.uint8)).save(buf, format="PNG")
    return buf.getvalue()


def images_zip(n: int) -> bytes:
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as zf:
        for i in range(n):
            zf.writestr(f"frame-{i:04d}.png", png(i))
    return buf.getvalue()


def wait_serving(gp: GridplaceClient, name: str, version: int, timeout_s: float = 20) -> None:
    """Until the server process has hot-swapped to ``version`` of ``name``."""
    deadline = time.monotonic() + timeout_s
    while gp.get_map(name).serving_version != version:
        assert time.monotonic() < deadline, f"{name} v{version} never served"
        time.sleep(0.05)

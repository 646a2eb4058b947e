"""Locating the real evaluation data (Nordland) that lies beside the project."""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from service.encoding.features import patch_normalize

NORDLAND_SHAPE = (32, 64)  # rows × columns of each frame in reference.npy / query.npy


def shared_data_dir() -> Path | None:
    """``GRIDPLACE_SHARED_DATA`` or ``../shared/data`` next to the working directory/checkout."""
    env = os.environ.get("GRIDPLACE_SHARED_DATA")
    candidates = [Path(env)] if env else []
    here = Path(__file__).resolve()
    candidates += [Path.cwd() / "../shared/data", here.parents[3] / "shared/data"]
    for c in candidates:
        if (c / "nordland-64x32" / "reference.npy").is_file():
            return c.resolve()
    return None


@dataclass(frozen=True)
class RealRoute:
    name: str
    reference: np.ndarray  # float32 descriptors
    query: np.ndarray
    label: str


def nordland(limit: int | None = None, patch: int = 16) -> RealRoute | None:
    """Nordland summer (reference) → winter (query), patch-normalised 64×32 frames."""
    root = shared_data_dir()
    if root is None:
        return None
    base = root / "nordland-64x32"
    ref = np.load(base / "reference.npy", allow_pickle=False)[:limit]
    qry = np.load(base / "query.npy", allow_pickle=False)[:limit]
    shape = (-1, *NORDLAND_SHAPE)
    return RealRoute(
        name="nordland-64x32",
        reference=patch_normalize(ref.reshape(shape), patch),
        query=patch_normalize(qry.reshape(shape), patch),
        label=f"Nordland summer→winter, {ref.shape[0]} frames, 64x32 patch-normalised ({patch}px)",
    )

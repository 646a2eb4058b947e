"""Fixtures for the training-backend tests. Every route here is SYNTHETIC."""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np
import pytest

from service.encoding.synthetic import smooth_route
from service.jobs.embedded import EmbeddedBackend
from service.registry import JobInfo, Registry
from service.settings import Settings


@pytest.fixture(scope="module")
def data_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("gridplace-data")


@pytest.fixture(scope="module")
def route_file(data_dir: Path) -> Path:
    """SYNTHETIC route (smooth random process), 360 frames × 32 features, stored like an upload."""
    path = data_dir / "uploads" / "synthetic-route.npy"
    path.parent.mkdir(parents=True, exist_ok=True)
    np.save(path, smooth_route(360, 32, seed=5).reference)
    return path


@pytest.fixture(scope="module")
def registry(data_dir: Path) -> Registry:
    return Registry(data_dir)


@pytest.fixture(scope="module")
def backend(data_dir: Path, registry: Registry) -> Iterator[EmbeddedBackend]:
    """One process pool for the module (starting one costs seconds)."""
    b = EmbeddedBackend(Settings(data_dir=data_dir, train_workers=2), registry)
    yield b
    b.close()


def _wait_done(backend: object, job_id: str, timeout: float = 60.0) -> JobInfo:
    deadline = time.monotonic() + timeout
    while True:
        job = backend.get_job(job_id)  # type: ignore[attr-defined]
        if job.done:
            return job
        if time.monotonic() > deadline:
            raise AssertionError(f"job {job_id} did not finish in {timeout} s: {job}")
        time.sleep(0.05)


@pytest.fixture()
def wait_done() -> Callable[..., JobInfo]:
    """``wait_done(backend, job_id, timeout=60)``: poll until the job finished."""
    return _wait_done

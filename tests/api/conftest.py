"""The REST app in-process over in-memory registry/backend fakes (see api_fakes.py)."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from api_fakes import FakeRegistry, InlineBackend
from api_helpers import TOKEN, npy_bytes
from fastapi.testclient import TestClient

from service.api.app import create_app
from service.core.context import build_context
from service.encoding.synthetic import smooth_route
from service.settings import Settings

N, D = 120, 32


@pytest.fixture
def route() -> tuple[np.ndarray, np.ndarray]:
    r = smooth_route(N, D, seed=1)  # SYNTHETIC
    return r.reference, r.query


@pytest.fixture
def settings(tmp_path: Path) -> Settings:
    return Settings(data_dir=tmp_path, admin_token=TOKEN, reload_interval_s=0.05,
                    max_upload_mb=2)  # fmt: skip


@pytest.fixture
def registry() -> FakeRegistry:
    return FakeRegistry()


@pytest.fixture
def backend(registry: FakeRegistry) -> InlineBackend:
    return InlineBackend(registry)


@pytest.fixture
def client(settings: Settings, registry: FakeRegistry, backend: InlineBackend) -> Iterator[TestClient]:
    ctx = build_context(settings, registry=registry, backend=backend)
    with TestClient(create_app(settings, context=ctx), raise_server_exceptions=False) as c:
        yield c


@pytest.fixture
def auth() -> dict[str, str]:
    return {"Authorization": f"Bearer {TOKEN}"}




@pytest.fixture
def trained(client: TestClient, auth: dict[str, str], route: tuple[np.ndarray, np.ndarray]) -> str:
    """Map 'synthetic' trained on the SYNTHETIC route and served."""
    r = client.post("/v1/maps/synthetic/routes", headers=auth,
                    files={"file": ("route.npy", npy_bytes(route[0]))},
                    data={"trainer": "ridge", "n_patterns": "2"})  # fmt: skip
    assert r.status_code == 202, r.text
    assert r.json()["state"] == "succeeded"
    client.app.state.context.store.refresh()  # type: ignore[attr-defined]
    return "synthetic"


"""Fixtures for the registry tests. Every route here is SYNTHETIC (smooth random process).

Every test that uses ``registry`` (or ``registry_url``) runs twice: on the embedded SQLite
file and on a real PostgreSQL (one scratch database per test module, emptied before each
test; ``GRIDPLACE_TEST_POSTGRES_URL`` names the server, default the local one on 5432). On
PostgreSQL, ``GRIDPLACE_REGISTRY_URL`` is set for the test, so every ``Registry`` it makes,
in this process or a child, uses that database.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

from service.encoding import ModelParams, PlaceRecognizer, build_model
from service.encoding.synthetic import SyntheticRoute, smooth_route
from service.errors import UnavailableError
from service.registry import Registry, VersionInfo
from service.registry.scratch import ScratchDatabase
from service.settings import get_settings

from registry_pg import empty_database

@pytest.fixture(scope="module")
def pg_url() -> Iterator[str]:
    """A scratch PostgreSQL database for this module (dropped after it)."""
    scratch = ScratchDatabase()
    try:
        url = scratch.create()
    except UnavailableError as exc:
        pytest.fail(f"the registry tests need a PostgreSQL server: {exc.message}")
    yield url
    scratch.drop()


@pytest.fixture(params=["sqlite", "postgresql"])
def registry_url(request: pytest.FixtureRequest, monkeypatch: pytest.MonkeyPatch) -> Iterator[str | None]:
    """``None`` (SQLite under data_dir) or the URL of an empty PostgreSQL registry."""
    if request.param == "sqlite":
        monkeypatch.delenv("GRIDPLACE_REGISTRY_URL", raising=False)
        get_settings.cache_clear()
        yield None
    else:
        url = request.getfixturevalue("pg_url")
        empty_database(url)
        monkeypatch.setenv("GRIDPLACE_REGISTRY_URL", url)
        get_settings.cache_clear()
        yield url
    monkeypatch.undo()
    get_settings.cache_clear()

PARAMS = ModelParams.parse(trainer="ridge", n_patterns=2, rho=0.5)


@pytest.fixture(scope="session")
def route() -> SyntheticRoute:
    """SYNTHETIC route: 240 frames × 32 features."""
    return smooth_route(240, 32, seed=11)


@pytest.fixture(scope="session")
def model(route: SyntheticRoute) -> PlaceRecognizer:
    return build_model(PARAMS).fit(route.reference)


@pytest.fixture(scope="session")
def other_model(route: SyntheticRoute) -> PlaceRecognizer:
    return build_model(ModelParams.parse(trainer="ridge", n_patterns=3)).fit(route.reference)


@pytest.fixture()
def registry(tmp_path: Path, registry_url: str | None) -> Iterator[Registry]:
    reg = Registry(tmp_path / "data")
    yield reg
    reg.close()


PublishFn = Callable[..., VersionInfo]


@pytest.fixture()
def publish(registry: Registry) -> PublishFn:
    """``publish(model, name="route-a", job_id=None, extractor=None)`` into ``registry``."""

    def _publish(
        model: PlaceRecognizer,
        name: str = "route-a",
        job_id: str | None = None,
        extractor: dict[str, Any] | None = None,
    ) -> VersionInfo:
        return registry.publish(
            name, model, params=PARAMS.model_dump(mode="json"), extractor=extractor,
            metrics={"train_seconds": 0.5}, job_id=job_id,
        )  # fmt: skip

    return _publish

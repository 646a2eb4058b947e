"""Fixtures for the registry tests. Every route here is SYNTHETIC (smooth random process)."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from service.encoding import ModelParams, PlaceRecognizer, build_model
from service.encoding.synthetic import SyntheticRoute, smooth_route
from service.registry import Registry, VersionInfo

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
def registry(tmp_path: Path) -> Registry:
    return Registry(tmp_path / "data")


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

"""Shared fixtures for the core library tests. All routes here are SYNTHETIC."""

from __future__ import annotations

import pytest

from service.encoding.synthetic import SyntheticRoute, smooth_route


@pytest.fixture(scope="session")
def small_route() -> SyntheticRoute:
    """SYNTHETIC smooth route: 400 frames × 48 features, noisy queries."""
    return smooth_route(400, 48, seed=7)


@pytest.fixture(scope="session")
def tiny_route() -> SyntheticRoute:
    """SYNTHETIC smooth route: 120 frames × 24 features."""
    return smooth_route(120, 24, seed=3)

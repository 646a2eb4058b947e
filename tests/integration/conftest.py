"""Fixtures of the integration tests: a real redis-server per module, real workers, a
scratch PostgreSQL registry per module."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
from rq_helpers import RedisServer, Workers

from service.registry.scratch import ScratchDatabase


@pytest.fixture(scope="module")
def redis_url() -> Iterator[str]:
    server = RedisServer().start()
    yield server.url
    server.stop()


@pytest.fixture()
def workers(redis_url: str) -> Iterator[Callable[..., Workers]]:
    started: list[Workers] = []

    def start(queue: str, n: int = 2, url: str | None = None, **kw: object) -> Workers:
        started.append(Workers(url or redis_url, queue, n, **kw))  # type: ignore[arg-type]
        return started[-1]

    yield start
    for w in started:
        w.stop()


@pytest.fixture(scope="module")
def pg_registry_url() -> Iterator[str]:
    """A scratch PostgreSQL database for the registry (dropped after the module)."""
    with ScratchDatabase() as url:
        yield url


@pytest.fixture()
def data_dir(tmp_path: Path) -> Path:
    (tmp_path / "uploads").mkdir()
    return tmp_path



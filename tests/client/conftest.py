"""One real ``gridplace serve`` process (free port, temp data dir) shared by the client tests.

Data is SYNTHETIC: a smooth random-process route (N=300, d=64) and tiny random PNG frames;
every training job uses trainer=ridge on the server's embedded backend.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from client_helpers import ENV, TOKEN, D, N, wait_serving

from service.api.process import ServerProcess
from service.client import GridplaceClient, Job
from service.encoding.synthetic import smooth_route


@pytest.fixture(scope="session")
def route() -> tuple[np.ndarray, np.ndarray]:
    r = smooth_route(N, D, seed=5)  # SYNTHETIC
    return r.reference, r.query


@pytest.fixture(scope="session")
def data_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("client-data")


@pytest.fixture(scope="session")
def server(data_dir: Path) -> Iterator[ServerProcess]:
    srv = ServerProcess(data_dir, env=ENV).start()
    try:
        yield srv
    finally:
        srv.stop()


@pytest.fixture(scope="session")
def gp(server: ServerProcess) -> Iterator[GridplaceClient]:
    with GridplaceClient(server.url, token=TOKEN, timeout=30) as client:
        yield client


@pytest.fixture(scope="session")
def synth(gp: GridplaceClient, route: tuple[np.ndarray, np.ndarray]) -> Job:
    """Map ``synth`` version 1, trained through the client from an ndarray."""
    job = gp.upload_route("synth", route[0], trainer="ridge", idempotency_key="synth-v1")
    again = gp.upload_route("synth", route[0], trainer="ridge", idempotency_key="synth-v1")
    assert again.id == job.id  # the idempotency key returned the same job
    seen: list[str] = []
    done = gp.wait_for_job(job.id, timeout=90, poll_interval=0.05,
                           on_update=lambda j: seen.append(j.state))  # fmt: skip
    assert done.state == "succeeded", done.error
    assert seen and seen[-1] == "succeeded"
    wait_serving(gp, "synth", done.version or 0)
    return done

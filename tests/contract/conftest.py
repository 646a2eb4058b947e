"""One real ``gridplace serve`` process for the API contract tests (defect reproductions and
the schemathesis run), over a data dir prepared in-process:

* map ``route``: a SYNTHETIC smooth route (N=160, d=24), trainer=ridge, active and served;
* map ``broken``: the same model whose artifact was corrupted on disk after publication;
* map ``nordland``: the same model again, the map the schema's examples name, for the fuzzer
  (which may deactivate or delete it: the other tests use ``route``).
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from pathlib import Path

import httpx
import numpy as np
import pytest
from contract_helpers import ENV, D, N

from service.api.process import ServerProcess
from service.encoding import ModelParams, build_model
from service.encoding.artifacts import TENSORS
from service.encoding.synthetic import smooth_route
from service.registry import Registry

PARAMS = ModelParams.parse(trainer="ridge", n_patterns=2)


@pytest.fixture(scope="session")
def contract_route() -> tuple[np.ndarray, np.ndarray]:
    r = smooth_route(N, D, seed=21)  # SYNTHETIC
    return r.reference, r.query


@pytest.fixture(scope="session")
def contract_data(tmp_path_factory: pytest.TempPathFactory,
                  contract_route: tuple[np.ndarray, np.ndarray]) -> Path:  # fmt: skip
    data_dir = tmp_path_factory.mktemp("contract-data")
    registry = Registry(data_dir)
    model = build_model(PARAMS).fit(contract_route[0])
    params = PARAMS.model_dump(mode="json")
    registry.publish("route", model, params=params, extractor=None, metrics={}, job_id=None)
    registry.publish("broken", model, params=params, extractor=None, metrics={}, job_id=None)
    registry.publish("nordland", model, params=params, extractor=None, metrics={}, job_id=None)
    tensors = registry.artifact_dir("broken", 1) / TENSORS
    tensors.chmod(0o644)
    blob = bytearray(tensors.read_bytes())
    blob[-16:] = bytes(16)  # flip the last weights: the recorded sha256 no longer matches
    tensors.write_bytes(bytes(blob))
    return data_dir


@pytest.fixture(scope="session")
def contract_server(contract_data: Path) -> Iterator[ServerProcess]:
    srv = ServerProcess(contract_data, env=ENV).start()
    try:
        yield srv
    finally:
        srv.stop()


@pytest.fixture(scope="session")
def api(contract_server: ServerProcess) -> Iterator[httpx.Client]:
    with httpx.Client(base_url=contract_server.url, timeout=30) as client:
        deadline = time.monotonic() + 30
        while "route" not in client.get("/readyz").json()["loaded"]:
            assert time.monotonic() < deadline, "map 'route' was never loaded"
            time.sleep(0.05)
        yield client

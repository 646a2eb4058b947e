"""The per-request work budget and the stop of abandoned drives, against a real
``gridplace serve`` with its default settings, on a SYNTHETIC map of 20,000 frames (d = 16).

Before: ``/v1/localize/sequence`` bounded frames × route length but not the speed grid (up to
129 states with ``reverse``, ``max_speed=50``, a small ``speed_step``); a 4,000-frame request
burned 42 s of CPU and went on after its client left."""

from __future__ import annotations

import time
from collections.abc import Iterator
from pathlib import Path

import httpx
import numpy as np
import psutil
import pytest

from service.api.process import ServerProcess
from service.encoding import ModelParams, build_model
from service.encoding.synthetic import smooth_route
from service.registry import Registry

pytestmark = pytest.mark.slow
N, D = 20_000, 16
WORST = {"min_speed": 0, "max_speed": 50, "speed_step": 50 / 63, "reverse": True,
         "stop_probability": 0.1}  # 2 × 64 speeds + a stopped state per direction: S = 130  # fmt: skip
S_WORST = 130
BUDGET = 1_000_000_000  # GRIDPLACE_MAX_REQUEST_WORK's default, 1,000 million units


@pytest.fixture(scope="module")
def queries() -> np.ndarray:
    return smooth_route(N, D, seed=5).query.astype(np.float32)  # SYNTHETIC


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[ServerProcess]:
    data: Path = tmp_path_factory.mktemp("work")
    route = smooth_route(N, D, seed=5)
    params = ModelParams.parse()
    Registry(data).publish("long", build_model(params).fit(route.reference),
                           params=params.model_dump(mode="json"), extractor=None, metrics={},
                           job_id=None)  # fmt: skip
    with ServerProcess(data, env={"GRIDPLACE_LOG_LEVEL": "info"}) as srv:
        srv.wait_ready(60)
        yield srv


def _drive(url: str, rows: np.ndarray, timeout: float = 120, **options: object) -> httpx.Response:
    return httpx.post(f"{url}/v1/localize/sequence", params={"map": "long", **options},
                      content=rows.tobytes(), timeout=timeout,
                      headers={"Content-Type": "application/octet-stream"})  # fmt: skip


def test_the_worst_drive_beyond_the_budget_is_413_before_any_work(server: ServerProcess,
                                                                  queries: np.ndarray) -> None:  # fmt: skip
    frames = BUDGET // (N * (S_WORST + 8)) + 1  # 363 frames: 1.0 × 10⁹ units
    cpu = psutil.Process(server.proc.pid)
    before = cpu.cpu_times()
    start = time.monotonic()
    r = _drive(server.url, queries[:frames], **WORST)
    took = time.monotonic() - start
    assert r.status_code == 413, r.text
    assert "GRIDPLACE_MAX_REQUEST_WORK" in r.json()["message"]
    assert f"(8 + {S_WORST} states)" in r.json()["message"]
    assert r.json()["details"] == {"work": frames * N * (S_WORST + 8), "budget": BUDGET}
    spent = sum(cpu.cpu_times()[:2]) - sum(before[:2])
    assert took < 5 and spent < 1.0, (took, spent)  # refused, not computed
    assert _drive(server.url, queries[: frames - 300], **WORST).status_code == 200


def test_a_batch_beyond_the_budget_is_413(server: ServerProcess, queries: np.ndarray) -> None:
    rows = BUDGET // (N * 8) + 1  # 6,251 rows × 20,000 frames × 8
    r = httpx.post(f"{server.url}/v1/localize/batch", params={"map": "long"}, timeout=60,
                   content=np.resize(queries, (rows, D)).tobytes(),
                   headers={"Content-Type": "application/octet-stream"})  # fmt: skip
    assert r.status_code == 413, r.text
    assert "GRIDPLACE_MAX_REQUEST_WORK" in r.json()["message"]
    ok = httpx.post(f"{server.url}/v1/localize/batch", timeout=60,
                    json={"map": "long", "descriptors": queries[:50].tolist()})  # fmt: skip
    assert ok.status_code == 200


def test_a_drive_stops_when_its_client_goes_away(server: ServerProcess, queries: np.ndarray) -> None:
    frames = BUDGET // (N * (S_WORST + 8))  # the most the budget allows: seconds of CPU
    proc = psutil.Process(server.proc.pid)
    with pytest.raises(httpx.ReadTimeout):
        _drive(server.url, queries[:frames], timeout=1.0, **WORST)  # the client leaves at 1 s
    left = time.monotonic()
    deadline = left + 10
    while "client went away" not in server.log() and time.monotonic() < deadline:
        time.sleep(0.1)
    stopped = time.monotonic() - left
    assert "client went away" in server.log(), server.log()[-2000:]
    time.sleep(0.3)
    idle_from = sum(proc.cpu_times()[:2])
    time.sleep(1.5)
    idle = sum(proc.cpu_times()[:2]) - idle_from
    assert stopped < 3 and idle < 0.3, (stopped, idle)  # the filter is no longer running
    assert _drive(server.url, queries[:20], **WORST).status_code == 200  # and the server serves

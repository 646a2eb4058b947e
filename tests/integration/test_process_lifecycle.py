"""The life of a ``gridplace serve`` process and of the training pool it starts, tested on real
processes: ports that are taken, Ctrl-C (SIGINT to the whole process group, as a terminal
sends it) and SIGTERM, and ``kill -9`` of the server in the middle of a training job.

Data is SYNTHETIC: a smooth random-process route (N=300, d=64) trained with ridge in a few
hundred milliseconds, and uniform noise (6000 × 512) trained with logreg, a job that runs for
tens of seconds and is interrupted about a second after it starts.
"""

from __future__ import annotations

import io
import os
import signal
import time
from collections.abc import Iterator
from typing import Any

import grpc
import httpx
import numpy as np
import process_tree
import pytest

from service.api.process import ServerProcess, free_port
from service.encoding.synthetic import smooth_route
from service.errors import UnavailableError
from service.grpc.gen import localization_pb2 as pb
from service.grpc.gen import localization_pb2_grpc as pb_grpc

pytestmark = pytest.mark.slow
TOKEN = "lifecycle-admin-token"
AUTH = {"Authorization": f"Bearer {TOKEN}"}
ENV = {"GRIDPLACE_ADMIN_TOKEN": TOKEN, "GRIDPLACE_RELOAD_INTERVAL_S": "0.2",
       "GRIDPLACE_LOG_LEVEL": "info"}  # fmt: skip


def _npy(X: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.save(buf, X, allow_pickle=False)
    return buf.getvalue()


def _upload(c: httpx.Client, name: str, X: np.ndarray, trainer: str) -> str:
    r = c.post(f"/v1/maps/{name}/routes", headers=AUTH, files={"file": ("r.npy", _npy(X))},
               data={"trainer": trainer})  # fmt: skip
    assert r.status_code == 202, r.text
    return str(r.json()["id"])


def _wait_state(c: httpx.Client, job_id: str, states: tuple[str, ...], timeout_s: float = 60) -> dict[str, Any]:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        job = c.get(f"/v1/jobs/{job_id}", headers=AUTH).json()
        if job["state"] in states:
            return job  # type: ignore[no-any-return]
        time.sleep(0.05)
    raise AssertionError(f"job {job_id} never reached {states}: {job}")


def _long_route() -> np.ndarray:
    """SYNTHETIC uniform noise: logreg needs tens of seconds for it."""
    return np.random.default_rng(3).random((6000, 512), dtype=np.float32)


def _pool_processes(srv: ServerProcess) -> list[int]:
    assert srv.proc is not None
    return process_tree.descendants(srv.proc.pid)


def _wait_pool(srv: ServerProcess, at_least: int, timeout_s: float = 30) -> list[int]:
    """The server's descendants once its training pool (forkserver, tracker, workers) runs."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        procs = _pool_processes(srv)
        if len(procs) >= at_least:
            return procs
        time.sleep(0.05)
    raise AssertionError(f"the training pool never started: {_pool_processes(srv)}")


def _list_maps(target: str) -> list[str]:
    with grpc.insecure_channel(target) as channel:  # a fresh channel: a fresh connection
        stub = pb_grpc.LocalizationStub(channel)
        reply = stub.ListMaps(pb.ListMapsRequest(), metadata=(("authorization", f"Bearer {TOKEN}"),),
                              timeout=10)  # fmt: skip
    return [m.name for m in reply.maps]


@pytest.fixture(scope="module")
def primary(tmp_path_factory: pytest.TempPathFactory) -> Iterator[ServerProcess]:
    """A server with REST and gRPC, in its own process group, holding map ``first``."""
    data_dir = tmp_path_factory.mktemp("primary")
    env = {**ENV, "GRIDPLACE_GRPC_PORT": str(free_port()), "GRIDPLACE_TRAIN_WORKERS": "2"}
    srv = ServerProcess(data_dir, env=env, new_session=True).start()
    try:
        with httpx.Client(base_url=srv.url, timeout=30) as c:
            job = _wait_state(c, _upload(c, "first", smooth_route(300, 64, seed=2).reference,
                                         "ridge"), ("succeeded", "failed"))  # fmt: skip
            assert job["state"] == "succeeded", job
        srv.wait_ready(30)
        yield srv
    finally:
        srv.stop()


def test_a_second_server_on_a_taken_grpc_port_fails_before_serving(primary, tmp_path) -> None:
    grpc_port = primary.env["GRIDPLACE_GRPC_PORT"]
    second = ServerProcess(tmp_path / "other", env={**ENV, "GRIDPLACE_GRPC_PORT": grpc_port})
    try:
        with pytest.raises(UnavailableError) as failed:
            second.start(timeout_s=60)  # returns only if the second server answered /healthz
    finally:
        second.stop()
    message = str(failed.value)
    assert "exited with 2" in message, message
    assert f"gRPC port 127.0.0.1:{grpc_port} is already in use" in message, message
    assert "Traceback" not in message, message
    # every fresh connection still reaches the first server (the only one holding map ``first``;
    # the module's other tests may have added maps to it)
    seen = [_list_maps(f"127.0.0.1:{grpc_port}") for _ in range(12)]
    with httpx.Client(base_url=primary.url, timeout=30) as c:
        held = sorted(m["name"] for m in c.get("/v1/maps", headers=AUTH).json())
    assert "first" in held and [sorted(m) for m in seen] == [held] * 12, (seen, held)


def test_a_taken_rest_port_fails_before_grpc_starts(primary, tmp_path) -> None:
    grpc_port = free_port()
    second = ServerProcess(tmp_path / "other", port=primary.port,
                           env={**ENV, "GRIDPLACE_GRPC_PORT": str(grpc_port)})  # fmt: skip
    second.log_path = tmp_path / "second.log"
    assert second.proc is None
    try:
        second.start(timeout_s=60)
    except UnavailableError:
        pass  # the /healthz it polls is the first server's, so it fails only once the child exits
    assert second.proc is not None
    code = second.proc.wait(30)
    log = second.log()
    second.stop()
    assert code == 2, log
    assert f"REST port 127.0.0.1:{primary.port} is already in use" in log, log
    assert "listening on" not in log, log  # the gRPC server never started
    assert "Traceback" not in log, log


def test_kill_9_of_the_server_takes_its_training_processes_with_it(primary) -> None:
    with httpx.Client(base_url=primary.url, timeout=30) as c:
        job_id = _upload(c, "long", _long_route(), "logreg")
        _wait_state(c, job_id, ("running",))
    pool = _wait_pool(primary, at_least=3)  # tracker, forkserver, worker
    assert primary.proc is not None
    old_pid = primary.proc.pid
    try:
        primary.proc.kill()
        primary.proc.wait()
        left = process_tree.wait_gone(pool, 10)
        assert left == [], [process_tree.describe(p) for p in left]
    finally:
        process_tree.kill_all([p for p in pool if process_tree.alive(p)])
    primary.start()  # a restart on the same data dir (the next test goes on with it)
    primary.wait_ready(30)
    with httpx.Client(base_url=primary.url, timeout=30) as c:
        job = c.get(f"/v1/jobs/{job_id}", headers=AUTH).json()
        versions = c.get("/v1/maps/long/versions", headers=AUTH)
    assert job["state"] == "failed", job
    assert f"server process {old_pid}" in job["error"], job
    assert versions.status_code == 404 or versions.json() == [], versions.text  # nothing half-published
    assert not set(pool) & set(process_tree.descendants(os.getpid()))


def test_ctrl_c_after_training_exits_0_quietly_and_fails_the_running_job(primary) -> None:
    """Ctrl-C reaches the server AND its pool processes (one idle, one training)."""
    with httpx.Client(base_url=primary.url, timeout=30) as c:
        job_id = _upload(c, "longer", _long_route(), "logreg")
        _wait_state(c, job_id, ("running",))
        short = _upload(c, "short", smooth_route(300, 64, seed=8).reference, "ridge")
        assert _wait_state(c, short, ("succeeded", "failed"))["state"] == "succeeded"
        before = _wait_pool(primary, at_least=4)  # tracker, forkserver, a busy and an idle worker
        time.sleep(0.5)  # the worker is inside the fit
        primary.interrupt(signal.SIGINT)
        assert primary.proc is not None
        code = primary.proc.wait(30)
    log = primary.log()
    assert code == 0, log
    assert "Traceback" not in log and "KeyboardInterrupt" not in log, log
    assert "leaked" not in log, log  # the resource tracker found nothing to clean up
    assert process_tree.wait_gone(before, 10) == [], [process_tree.describe(p) for p in before]
    from service.registry import Registry

    job = Registry(primary.data_dir).get_job(job_id)
    assert job.state == "failed" and "server shut down" in (job.error or ""), job
    primary.start()  # a restart on the same data dir (the module's other tests go on with it)
    primary.wait_ready(30)



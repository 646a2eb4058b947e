"""A training job whose registry goes away mid-fit: a real ``gridplace serve`` on a private
PostgreSQL cluster, which is killed (``kill -9`` of the postmaster) while the job runs and
restarted 8 s later. Before, the failure path's registry write raised ``UnavailableError``,
was swallowed without a log line, and the job read ``running`` for good; a re-upload of the
same route answered 200 ``reused: true`` with that stuck job."""

from __future__ import annotations

import signal
import time
from collections.abc import Iterator
from pathlib import Path

import httpx
import numpy as np
import psutil
import pytest

from pg_cluster import PostgresCluster
from service.api.process import ServerProcess
from service.encoding.synthetic import smooth_route
from test_server import AUTH, TOKEN, _npy, _upload

pytestmark = pytest.mark.slow
N, D = 3000, 64


@pytest.fixture()
def cluster() -> Iterator[PostgresCluster]:
    pg = PostgresCluster().start()
    yield pg
    pg.destroy()


def _kill_postgres(pg: PostgresCluster) -> None:
    """kill -9 of the postmaster and of every backend (as a crash of its host would)."""
    postmaster = psutil.Process(int((pg.data / "postmaster.pid").read_text().split()[0]))
    processes = [postmaster, *postmaster.children(recursive=True)]
    for proc in processes:
        proc.send_signal(signal.SIGKILL)
    psutil.wait_procs(processes, timeout=10)


def _state(c: httpx.Client, job_id: str) -> dict:
    r = c.get(f"/v1/jobs/{job_id}", headers=AUTH)
    return r.json() if r.status_code == 200 else {"state": f"http {r.status_code}"}


def test_a_job_failing_while_the_registry_is_down_is_recorded_when_it_is_back(
    cluster: PostgresCluster, tmp_path: Path
) -> None:
    env = {"GRIDPLACE_ADMIN_TOKEN": TOKEN, "GRIDPLACE_REGISTRY_URL": cluster.url,
           "GRIDPLACE_TRAIN_WORKERS": "1", "GRIDPLACE_LOG_LEVEL": "info",
           "GRIDPLACE_REGISTRY_CONNECT_TIMEOUT_S": "1"}  # fmt: skip
    X = smooth_route(N, D, seed=31).reference.astype(np.float32)  # SYNTHETIC
    with ServerProcess(tmp_path / "data", env=env) as srv, \
            httpx.Client(base_url=srv.url, timeout=60) as c:  # fmt: skip
        first = _upload(c, "outage", _npy(X), encoder_preset="paper")
        assert first.status_code == 202, first.text
        job_id = first.json()["id"]
        deadline = time.monotonic() + 60
        while _state(c, job_id)["state"] == "queued" and time.monotonic() < deadline:
            time.sleep(0.05)
        assert _state(c, job_id)["state"] == "running"
        _kill_postgres(cluster)
        time.sleep(8)
        cluster.start()
        deadline = time.monotonic() + 60
        while (job := _state(c, job_id))["state"] not in ("failed", "succeeded"):
            assert time.monotonic() < deadline, f"the job stayed {job['state']}: {srv.log()[-3000:]}"
            time.sleep(0.2)
        if job["state"] == "failed":  # it failed during the outage: recorded once back, logged
            log = srv.log_path.read_text()
            assert "but the registry is unreachable" in log and "recording it when" in log
            assert "its failure is recorded now that the registry is back" in log
        again = _upload(c, "outage", _npy(X), encoder_preset="paper")
        if job["state"] == "failed":
            assert again.status_code == 202 and again.json()["id"] != job_id, again.text
        else:
            assert again.status_code == 200 and again.json()["version"] == job["version"]

"""Replicated `gridplace serve` processes on one PostgreSQL registry and one artifact store,
and a registry database that goes away under traffic. Real server processes, real
PostgreSQL (a scratch database on the shared server; for the outage, a private cluster on a
free port). Routes are SYNTHETIC (smooth random process), trained with ridge.
"""

from __future__ import annotations

import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from typing import Any

import httpx
import numpy as np
import pytest

from pg_cluster import PostgresCluster
from service.api.process import ServerProcess
from service.encoding.synthetic import smooth_route
from test_server import AUTH, TOKEN, _npy, _upload, _wait_job

pytestmark = pytest.mark.slow
RELOAD_S = 0.5
N, D = 300, 64


def _env(registry_url: str) -> dict[str, str]:
    return {"GRIDPLACE_ADMIN_TOKEN": TOKEN, "GRIDPLACE_REGISTRY_URL": registry_url,
            "GRIDPLACE_RELOAD_INTERVAL_S": str(RELOAD_S), "GRIDPLACE_TRAIN_WORKERS": "1"}  # fmt: skip


class Load(threading.Thread):
    """Localize requests in a loop against one server: every answer's send and answer
    times, status and version."""

    def __init__(self, url: str, map_name: str, q: np.ndarray) -> None:
        super().__init__(daemon=True)
        self.url, self.map, self.q = url, map_name, q
        self.answers: list[tuple[float, float, int, int | None]] = []
        self.stop = threading.Event()

    def run(self) -> None:
        with httpx.Client(base_url=self.url, timeout=10) as c:
            i = 0
            while not self.stop.is_set() and len(self.answers) < 20_000:
                sent = time.monotonic()
                r = c.post("/v1/localize", json={"map": self.map,
                                                  "descriptor": self.q[i % len(self.q)].tolist()})
                version = r.json().get("version") if r.status_code == 200 else None
                self.answers.append((sent, time.monotonic(), r.status_code, version))
                i += 1

    def finish(self) -> list[tuple[float, float, int, int | None]]:
        self.stop.set()
        self.join(timeout=30)
        return self.answers

    def first(self, version: int, after: float) -> float:
        return min(t for _, t, s, v in self.answers if v == version and t >= after)

    def versions_sent_between(self, start: float, end: float) -> set[int | None]:
        return {v for sent, _, _, v in self.answers if start <= sent and sent < end}


@pytest.fixture()
def replicas(tmp_path, pg_registry_url) -> Iterator[tuple[ServerProcess, ServerProcess]]:
    data = tmp_path / "shared-data"  # one artifact store (RWX storage in production)
    a = ServerProcess(data, env=_env(pg_registry_url), log_path=tmp_path / "a.log").start()
    try:
        b = ServerProcess(data, env=_env(pg_registry_url), log_path=tmp_path / "b.log").start()
    except BaseException:
        a.stop()
        raise
    yield a, b
    b.stop()
    a.stop()


def test_two_replicas_share_versions_jobs_and_activations(replicas, tmp_path):
    a, b = replicas
    X = smooth_route(N, D, seed=21).reference.astype(np.float32)
    narrow = smooth_route(N, D // 2, seed=22).reference.astype(np.float32)
    with httpx.Client(base_url=a.url, timeout=60) as ca, httpx.Client(base_url=b.url,
                                                                    timeout=60) as cb:
        first = _upload(ca, "city", _npy(X))
        assert first.status_code == 202, first.text
        assert _wait_job(cb, first.json()["id"])["version"] == 1  # B sees A's job
        # the same route again (through the other replica): the existing job, nothing queued
        again = _upload(cb, "city", _npy(X))
        assert again.status_code == 200 and again.json()["reused"] is True
        assert (again.json()["id"], again.json()["version"]) == (first.json()["id"], 1)
        forced = _upload(cb, "city", _npy(X), force="true")
        assert forced.status_code == 202 and forced.json()["id"] != first.json()["id"]
        assert _wait_job(ca, forced.json()["id"])["version"] == 2
        # another descriptor width: refused unless said explicitly, then recorded
        refused = _upload(ca, "city", _npy(narrow))
        assert refused.status_code == 409 and refused.json()["error"] == "dimension_change"
        assert "allow_dimension_change" in refused.json()["message"]
        wide = _upload(ca, "city", _npy(narrow), allow_dimension_change="true")
        assert wide.status_code == 202
        assert _wait_job(ca, wide.json()["id"])["version"] == 3
        v3 = cb.get("/v1/maps/city/versions/3", headers=AUTH).json()
        assert v3["extra"]["dimension_change"] == {"from": D, "to": D // 2,
                                                   "reference_version": 1}  # fmt: skip
        assert v3["content_sha256"] and v3["content_sha256"] != first.json()["content_sha256"]
        # the job list, from either replica, newest first, paginated and filtered
        ids = [wide.json()["id"], forced.json()["id"], first.json()["id"]]
        page = cb.get("/v1/jobs", params={"map": "city"}, headers=AUTH).json()
        assert [j["id"] for j in page["jobs"]] == ids and page["next_cursor"] is None
        seen, cursor = [], None
        while True:
            params: dict[str, Any] = {"limit": 1, **({"cursor": cursor} if cursor else {})}
            page = ca.get("/v1/jobs", params=params, headers=AUTH).json()
            seen += [j["id"] for j in page["jobs"]]
            if not (cursor := page["next_cursor"]):
                break
        assert seen == ids
        bad = ca.get("/v1/jobs", params={"state": "done"}, headers=AUTH)
        assert bad.status_code == 422 and "state" in bad.json()["message"]  # the schema's enum
        assert ca.get("/v1/jobs", params={"state": ["failed"]}, headers=AUTH).json()["jobs"] == []
        cli = subprocess.run(
            [sys.executable, "-m", "service.cli", "client", "jobs", "--map", "city", "--url",
             a.url, "--token", TOKEN, "--json"], capture_output=True, timeout=60, check=False,
        )  # fmt: skip
        assert cli.returncode == 0, cli.stderr.decode()
        assert all(i in cli.stdout.decode() for i in ids)

        # activation through A under load on both: zero failures, both serve v2 in time
        loads = [Load(s.url, "city", X[::7]) for s in (a, b)]
        for load in loads:
            load.start()
        time.sleep(0.5)
        t_activate = time.monotonic()
        assert ca.post("/v1/maps/city/versions/2/activate", headers=AUTH).status_code == 200
        t_activated = time.monotonic()
        time.sleep(3 * RELOAD_S + 1.0)
        t_rollback = time.monotonic()
        assert cb.post("/v1/maps/city/versions/1/activate", headers=AUTH).status_code == 200
        time.sleep(3 * RELOAD_S + 1.0)
        answers = [load.finish() for load in loads]
    assert all(len(ans) > 50 for ans in answers), [len(x) for x in answers]
    failed = [(t, s) for ans in answers for _, t, s, _ in ans if s != 200]
    assert failed == []
    lag_b = loads[1].first(2, t_activate) - t_activate  # B learns of A's activation by polling
    lag_a = loads[0].first(1, t_rollback) - t_rollback  # and A of B's rollback
    assert lag_b <= RELOAD_S + 1.0 and lag_a <= RELOAD_S + 1.0, (lag_a, lag_b)
    # A switched when it answered: every request sent to it after that is served by v2
    assert loads[0].versions_sent_between(t_activated, t_rollback) == {2}


def test_localize_rides_out_a_postgres_outage_and_admin_calls_recover(tmp_path):
    cluster = PostgresCluster().start()
    try:
        env = _env(cluster.url)
        X = smooth_route(N, D, seed=23).reference.astype(np.float32)
        with ServerProcess(tmp_path / "data", env=env, log_path=tmp_path / "s.log") as srv, \
                httpx.Client(base_url=srv.url, timeout=30) as c:  # fmt: skip
            job = _upload(c, "route", _npy(X)).json()
            assert _wait_job(c, job["id"])["state"] == "succeeded"
            srv.wait_ready()
            load = Load(srv.url, "route", X[::5])
            load.start()
            time.sleep(0.5)
            cluster.stop()
            t_down = time.monotonic()
            time.sleep(2 * RELOAD_S)
            down = c.get("/v1/maps", headers=AUTH)
            assert down.status_code == 503 and down.json()["error"] == "unavailable"
            assert "registry database" in down.json()["message"]
            assert c.get("/v1/jobs", headers=AUTH).status_code == 503
            assert c.get("/metrics").status_code == 200
            time.sleep(1.0)
            cluster.start()
            t_up = time.monotonic()
            deadline = t_up + 30
            while (r := c.get("/v1/maps", headers=AUTH)).status_code != 200:
                assert time.monotonic() < deadline, r.text
                time.sleep(0.2)
            recovered_s = time.monotonic() - t_up
            assert r.json()[0]["name"] == "route"
            time.sleep(0.5)
            answers = load.finish()
        during = [s for _, t, s, _ in answers if t_down <= t <= t_up]
        assert len(during) > 20 and set(during) == {200}  # answered from memory
        assert {s for _, _, s, _ in answers} == {200}
        assert recovered_s < 15
        assert "serving the loaded versions" in (tmp_path / "s.log").read_text()
    finally:
        cluster.destroy()

"""Real Redis servers and real `gridplace worker` processes for the RQ integration tests.
Routes are SYNTHETIC (smooth random process)."""

from __future__ import annotations

import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from redis import Redis
from redis.exceptions import RedisError
from rq import Worker
from rq.job import Job
from rq.registry import StartedJobRegistry

from service.encoding.synthetic import smooth_route
from service.jobs import make_backend
from service.jobs.rq_backend import RQBackend
from service.jobs.rq_tasks import SERIALIZER
from service.registry import JobInfo, Registry
from service.settings import Settings


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class RedisServer:
    """A real ``redis-server`` on a free port, nothing persisted; stop() and start() again
    on the same port to simulate an outage (the restarted server is empty)."""

    def __init__(self) -> None:
        exe = shutil.which("redis-server")
        if exe is None:
            pytest.fail("redis-server is not on PATH; the RQ integration tests need a real Redis "
                        "(install it, e.g. apt-get install redis-server)")  # fmt: skip
        self.exe = exe
        self.port = _free_port()
        self.url = f"redis://127.0.0.1:{self.port}/0"
        self.proc: subprocess.Popen[bytes] | None = None

    def start(self) -> RedisServer:
        self.proc = subprocess.Popen(
            [self.exe, "--port", str(self.port), "--bind", "127.0.0.1", "--save", "",
             "--appendonly", "no"], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
        )  # fmt: skip
        client = Redis.from_url(self.url)
        deadline = time.monotonic() + 10
        try:
            while True:
                try:
                    client.ping()
                    return self
                except RedisError:
                    if self.proc.poll() is not None or time.monotonic() > deadline:
                        self.stop()
                        pytest.fail(f"redis-server did not start on port {self.port}")
                    time.sleep(0.05)
        finally:
            client.close()

    def stop(self) -> None:
        if self.proc is not None:
            self.proc.terminate()
            self.proc.wait(timeout=10)
            self.proc = None


def _children(pid: int) -> list[int]:
    """Direct children of ``pid`` (from /proc)."""
    out = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[1]) == pid:
            out.append(int(stat.parent.name))
    return out


class Workers:
    """Real ``gridplace worker`` subprocesses, each in its own process group."""

    def __init__(self, redis_url: str, queue: str, n: int, env: dict[str, str] | None = None,
                 log_dir: Path | None = None) -> None:  # fmt: skip
        self.redis = Redis.from_url(redis_url)
        self.queue = queue
        self.procs: dict[str, subprocess.Popen[bytes]] = {}
        self.logs: dict[str, Path] = {}
        for i in range(n):
            name = f"{queue}-w{i}"
            out = subprocess.DEVNULL
            if log_dir is not None:
                self.logs[name] = log_dir / f"{name}.log"
                out = open(self.logs[name], "wb")  # noqa: SIM115 - owned by the child
            self.procs[name] = subprocess.Popen(
                [sys.executable, "-m", "service.cli", "worker", "--redis-url", redis_url,
                 "--queue", queue, "--name", name, "--monitoring-interval", "1",
                 "--heartbeat-grace", "2", "--maintenance-interval", "2"],
                stdout=out, stderr=subprocess.STDOUT, start_new_session=True,
                env={**os.environ, **(env or {})},
            )  # fmt: skip
            if out is not subprocess.DEVNULL:
                out.close()
        deadline = time.monotonic() + 60
        while len(Worker.all(connection=self.redis)) < len(self.procs) or not self._all_listed():
            if time.monotonic() > deadline:
                self.stop()
                raise AssertionError("the gridplace workers did not register with Redis")
            time.sleep(0.1)

    def _all_listed(self) -> bool:
        names = {w.name for w in Worker.all(connection=self.redis)}
        return set(self.procs) <= names

    def kill(self, name: str) -> None:
        """SIGKILL a worker and its work horse (RQ puts the horse in its own process group),
        as if the host died: nothing gets to clean up or report."""
        proc = self.procs[name]
        horses = _children(proc.pid)
        os.killpg(proc.pid, signal.SIGKILL)
        for pid in horses:
            try:
                os.kill(pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
        proc.wait(timeout=10)

    def stop(self) -> None:
        for proc in self.procs.values():
            if proc.poll() is None:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait(timeout=10)
        self.redis.close()


def _route(data_dir: Path, n: int, d: int, seed: int = 0) -> Path:
    """A SYNTHETIC route stored like an upload."""
    path = data_dir / "uploads" / f"synthetic-{n}x{d}-{seed}.npy"
    np.save(path, smooth_route(n, d, seed=seed).reference)
    return path


def _backend(data_dir: Path, redis_url: str, queue: str, registry_url: str | None = None,
             **settings_kw: object) -> tuple[RQBackend, Registry]:  # fmt: skip
    registry = Registry(data_dir, url=registry_url)
    settings_kw = {"job_retry_backoff_s": 1, "reconcile_interval_s": 0, **settings_kw}
    settings = Settings(data_dir=data_dir, redis_url=redis_url, queue_name=queue,
                        **settings_kw)  # type: ignore[arg-type]  # fmt: skip
    backend = make_backend(settings, registry)
    assert isinstance(backend, RQBackend)
    return backend, registry


def _wait(backend: RQBackend, job_id: str, timeout: float = 60.0) -> JobInfo:
    deadline = time.monotonic() + timeout
    while True:
        job = backend.get_job(job_id)
        if job.done:
            return job
        assert time.monotonic() < deadline, f"job did not finish in {timeout} s: {job}"
        time.sleep(0.1)


def _running_chunk(backend: RQBackend, job_id: str, chunk_ids: set[str]) -> Job:
    started = StartedJobRegistry(queue=backend.queue)
    deadline = time.monotonic() + 60
    while True:
        assert time.monotonic() < deadline, f"no chunk part started: {backend.get_job(job_id)}"
        running = chunk_ids & set(started.get_job_ids(cleanup=False))
        if running:
            part = Job.fetch(min(running), connection=backend.queue.connection,
                             serializer=SERIALIZER)  # fmt: skip
            if part.worker_name:
                return part
        time.sleep(0.02)

"""Redis outages and stragglers, with real `gridplace worker` processes and a real
redis-server that the test stops and restarts (empty, as a Redis without persistence
comes back). Routes are SYNTHETIC (smooth random process)."""

from __future__ import annotations

import time
import uuid
from datetime import timedelta

import pytest
from rq.job import Job
from rq.registry import StartedJobRegistry

from rq_helpers import RedisServer, _backend, _route, _running_chunk, _wait
from service.encoding import ModelParams
from service.jobs import rq_backend
from service.jobs.rq_tasks import SERIALIZER, part_ids
from service.jobs.workspace import Workspace, sweep_workspaces


@pytest.fixture()
def own_redis():
    server = RedisServer().start()
    yield server
    server.stop()


def test_busy_workers_ride_out_a_redis_restart_and_the_stranded_job_fails(
    data_dir, own_redis, workers, monkeypatch
):
    """Both workers are training when Redis goes away for a few seconds and comes back
    empty: neither worker exits, the job in flight (whose parts Redis forgot, while the
    stragglers still finish theirs) fails with the reason within one reconciliation, and
    the same workers train the next route."""
    monkeypatch.setattr(rq_backend, "LOST_AFTER", timedelta(seconds=1))
    queue = f"q-{uuid.uuid4().hex[:8]}"
    pool = workers(queue, 2, url=own_redis.url, log_dir=data_dir)
    backend, registry = _backend(data_dir, own_redis.url, queue)
    route = _route(data_dir, 2400, 256, seed=7)  # chunk parts train for a few seconds
    job = backend.submit("outage", route, ModelParams.parse(trainer="logreg", n_chunks=2),
                         None, None)  # fmt: skip
    chunks = {part_ids(job.id, 2)[f"chunk-{c}"] for c in range(2)}
    started = StartedJobRegistry(queue=backend.queue)
    deadline = time.monotonic() + 60
    while not chunks <= set(started.get_job_ids(cleanup=False)):
        assert time.monotonic() < deadline, f"both chunks never ran: {registry.get_job(job.id)}"
        time.sleep(0.02)
    own_redis.stop()  # both workers are busy in their horse-monitoring loop
    time.sleep(4.0)
    assert all(p.poll() is None for p in pool.procs.values()), "a busy worker died"
    own_redis.start()  # empty: the queue forgot the job's parts
    deadline = time.monotonic() + 60
    while not (got := backend.get_job(job.id)).done:
        assert time.monotonic() < deadline, got
        time.sleep(0.2)
    assert got.state == "failed" and "cannot finish" in got.error, got.error
    assert registry.version_for_job(job.id) is None
    assert all(p.poll() is None for p in pool.procs.values()), "a worker exited after Redis came back"
    # the workers are registered again and train the next route
    nxt = backend.submit("after", _route(data_dir, 300, 32), ModelParams.parse(trainer="ridge",
                         n_chunks=2), None, None)  # fmt: skip
    assert _wait(backend, nxt.id, timeout=60).state == "succeeded"
    time.sleep(1.0)  # let the stragglers finish: they must not bring the workspace back
    assert not (data_dir / "jobs" / job.id).exists()
    logs = "".join(p.read_text(errors="replace") for p in pool.logs.values())
    assert "Redis unreachable" in logs and "reachable again" in logs
    backend.close()


def test_a_straggling_chunk_does_not_recreate_a_failed_jobs_workspace(
    data_dir, redis_url, workers
):
    queue = f"q-{uuid.uuid4().hex[:8]}"
    workers(queue, 1)
    backend, registry = _backend(data_dir, redis_url, queue)
    job = backend.submit("straggler", _route(data_dir, 1600, 256, seed=8),
                         ModelParams.parse(trainer="logreg", n_chunks=2), None, None)  # fmt: skip
    victim = part_ids(job.id, 2)["chunk-0"]
    _running_chunk(backend, job.id, {victim})
    # another part failed meanwhile: the job fails and its workspace goes (as fail_job does)
    assert registry.fail_job(job.id, "chunk-1 failed: simulated")
    Workspace(data_dir, job.id).remove()
    deadline = time.monotonic() + 60
    part = Job.fetch(victim, connection=backend.queue.connection, serializer=SERIALIZER)
    while part.get_status() not in ("finished", "failed"):
        assert time.monotonic() < deadline, "the straggling chunk never finished"
        time.sleep(0.05)
    assert part.get_status() == "finished" and "skipped" in (part.return_value() or {})
    assert not (data_dir / "jobs" / job.id).exists()
    assert registry.get_job(job.id).state == "failed"
    backend.close()


def test_orphaned_workspaces_are_swept(data_dir, redis_url):
    import os

    backend, registry = _backend(data_dir, redis_url, "sweep")
    running, _ = registry.create_job("m", route=_route(data_dir, 50, 8), params={},
                                     extractor=None, backend="rq")  # fmt: skip
    failed, _ = registry.create_job("m", route=_route(data_dir, 50, 8), params={"rho": 0.5},
                                    extractor=None, backend="rq")  # fmt: skip
    registry.fail_job(failed.id, "x")
    dirs = {name: data_dir / "jobs" / name for name in (running.id, failed.id, "unknown-job")}
    old = time.time() - 3600
    for path in dirs.values():
        (path / "chunk-00000").mkdir(parents=True)
        os.utime(path, (old, old))
    fresh = data_dir / "jobs" / "just-now"
    fresh.mkdir()
    removed = sweep_workspaces(registry)
    assert sorted(removed) == sorted([dirs[failed.id], dirs["unknown-job"]])
    assert dirs[running.id].exists() and fresh.exists()  # a running job's, a young one
    backend.close()

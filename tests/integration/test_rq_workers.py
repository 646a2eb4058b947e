"""Distributed training on real RQ workers against a real Redis.

Starts its own ``redis-server`` on a free port (nothing persisted) and real ``gridplace
worker`` processes. A missing ``redis-server`` is a failure, not a skip: the distributed queue
is part of the product. Routes are SYNTHETIC (smooth random process).
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
import uuid

import numpy as np
import pytest
from rq import Worker
from rq.job import Job
from rq_helpers import _backend, _children, _free_port, _route, _running_chunk, _wait

from service.encoding import ModelParams, build_model
from service.errors import NotFoundError, UnavailableError
from service.jobs.rq_backend import RQBackend
from service.jobs.rq_tasks import SERIALIZER, part_ids
from service.registry import Registry
from service.settings import Settings


def test_chunks_train_in_parallel_on_several_workers(data_dir, redis_url, workers):
    queue = f"q-{uuid.uuid4().hex[:8]}"
    workers(queue, 2)
    backend, registry = _backend(data_dir, redis_url, queue)
    route = _route(data_dir, 1600, 64)
    params = ModelParams.parse(trainer="ridge", n_chunks=4)
    backend.check_available()
    job = backend.submit("city", route, params, None, "upload-1")
    assert backend.submit("city", route, params, None, "upload-1").id == job.id  # idempotent
    done = _wait(backend, job.id)
    assert done.state == "succeeded", done.error
    assert (done.chunks_done, done.chunks_total, done.version) == (5, 5, 1)
    # each part's fit progress was written by the worker that ran it
    assert set(done.progress.parts) == {"chunk_0", "chunk_1", "chunk_2", "chunk_3", "chunk_classifier"}
    assert all(p.done == p.total > 0 for p in done.progress.parts.values())
    info = registry.get_version("city", 1)
    assert info.active and info.kind == "chunked_encoder" and info.metrics["backend"] == "rq"
    # every part ran as its own RQ job; the chunk parts were spread over both workers
    ids = part_ids(job.id, 4)
    parts = Job.fetch_many(list(ids.values()), connection=backend.queue.connection,
                           serializer=SERIALIZER)  # fmt: skip
    assert all(p is not None for p in parts)
    # parts before the assembly finished before it started; the assembly records its own
    # RQ result a moment after publishing
    assert all(p.get_status() == "finished" for p in parts if "-assemble" not in p.id)
    chunk_workers = {p.worker_name for p in parts if p is not None and "-chunk-" in p.id}
    assert len(chunk_workers) == 2
    X = np.load(route)
    served = registry.load_model("city", 1)
    np.testing.assert_array_equal(served.predict(X[::7]), build_model(params).fit(X).predict(X[::7]))
    assert not (data_dir / "jobs" / job.id).exists()
    assert backend.queue_depth() == 0
    backend.close()


def test_unchunked_route_and_a_failing_route(data_dir, redis_url, workers):
    queue = f"q-{uuid.uuid4().hex[:8]}"
    workers(queue, 1)
    backend, registry = _backend(data_dir, redis_url, queue)
    route = _route(data_dir, 300, 32)
    ok = backend.submit("small", route, ModelParams.parse(trainer="ridge"), None, None)
    bad = backend.submit("broken", route, ModelParams.parse(trainer="ridge", n_chunks=2,
                                                            periods=(3, 3), code="mixed_radix"),
                           None, None)  # fmt: skip
    assert _wait(backend, ok.id).version == 1
    failed = _wait(backend, bad.id)
    assert failed.state == "failed" and "product of periods" in failed.error
    with pytest.raises(NotFoundError):
        registry.get_map("broken")
    assert backend.queue_depth() == 0  # the waiting parts were cancelled
    backend.close()


def test_a_worker_killed_mid_chunk_is_retried_and_the_route_publishes(
    data_dir, redis_url, workers, pg_registry_url
):
    """SIGKILL of a `gridplace worker` (and its training process) mid-chunk, on a PostgreSQL
    registry: the chunk runs again on the other worker, the version is published, and the
    job shows the retry."""
    queue = f"q-{uuid.uuid4().hex[:8]}"
    pool = workers(queue, 2, env={"GRIDPLACE_REGISTRY_URL": pg_registry_url})
    backend, registry = _backend(data_dir, redis_url, queue, pg_registry_url)
    route = _route(data_dir, 1200, 256, seed=3)  # chunk parts take about a second each
    params = ModelParams.parse(trainer="logreg", n_chunks=2)
    job = backend.submit("survivor", route, params, None, None)
    chunk_ids = {part_ids(job.id, 2)[f"chunk-{c}"] for c in range(2)}
    part = _running_chunk(backend, job.id, chunk_ids)
    assert part.worker_name in pool.procs
    pool.kill(part.worker_name)  # mid-chunk: no exception handler, no callback, no heartbeat
    done = _wait(backend, job.id, timeout=90)
    assert done.state == "succeeded", done
    assert done.version == 1 and done.chunks_done == done.chunks_total == 3
    killed = part.id.removeprefix(f"gridplace-{job.id}-")
    assert [(r.part, r.attempt) for r in done.retries] == [(killed, 1)]
    assert "heartbeat" in done.retries[0].error
    X = np.load(route)
    served = registry.load_model("survivor", 1)
    np.testing.assert_array_equal(served.predict(X[::5]), build_model(params).fit(X).predict(X[::5]))
    assert not (data_dir / "jobs" / job.id).exists()
    backend.close()


def test_a_chunk_killed_on_every_attempt_fails_the_route_with_its_error(
    data_dir, redis_url, workers
):
    """The OOM-killer case on every attempt: the work horse dies, its worker survives and
    reports it; after the last retry the route fails with the chunk's error, no version."""
    queue = f"q-{uuid.uuid4().hex[:8]}"
    pool = workers(queue, 1)
    backend, registry = _backend(data_dir, redis_url, queue, job_retries=1)
    route = _route(data_dir, 1200, 256, seed=4)
    job = backend.submit("oom", route, ModelParams.parse(trainer="logreg", n_chunks=2), None, None)
    proc = next(iter(pool.procs.values()))
    victim = part_ids(job.id, 2)["chunk-0"]
    for attempt in (1, 2):
        deadline = time.monotonic() + 60
        while True:  # the worker runs chunk-0 (not another part) in a forked work horse
            current = [w.get_current_job_id() for w in Worker.all(connection=pool.redis)]
            if victim in current and (horses := _children(proc.pid)):
                break
            assert time.monotonic() < deadline, f"chunk-0 attempt {attempt} never ran"
            time.sleep(0.01)
        for pid in horses:
            os.kill(pid, signal.SIGKILL)
        while attempt == 1 and not registry.get_job(job.id).retries:
            assert time.monotonic() < deadline, registry.get_job(job.id)
            time.sleep(0.02)
    deadline = time.monotonic() + 30
    while not (got := registry.get_job(job.id)).done:  # no polling of the backend needed
        assert time.monotonic() < deadline, got
        time.sleep(0.05)
    assert got.state == "failed" and got.error.startswith("chunk-0 failed")
    assert "killed by signal 9" in got.error, got.error
    assert [(r.part, r.attempt) for r in got.retries] == [("chunk-0", 1)]
    assert registry.version_for_job(job.id) is None
    with pytest.raises(NotFoundError):
        registry.get_map("oom")
    assert proc.poll() is None  # the worker itself lives on
    assert backend.queue_depth() == 0
    backend.close()


def test_burst_worker_drains_the_queue_and_exits(data_dir, redis_url):
    queue = f"q-{uuid.uuid4().hex[:8]}"
    backend, registry = _backend(data_dir, redis_url, queue)
    job = backend.submit("burst", _route(data_dir, 240, 16), ModelParams.parse(trainer="ridge",
                         n_chunks=2), None, None)  # fmt: skip
    proc = subprocess.run(
        [sys.executable, "-m", "service.cli", "worker", "--redis-url", redis_url, "--queue", queue,
         "--burst"], capture_output=True, timeout=120, check=False,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr.decode()[-2000:]
    done = backend.get_job(job.id)
    assert done.state == "succeeded" and registry.get_map("burst").active_version == 1
    assert backend.queue_depth() == 0
    backend.close()


def test_worker_without_redis_exits_with_a_clear_error():
    url = f"redis://127.0.0.1:{_free_port()}/0"
    proc = subprocess.run(
        [sys.executable, "-m", "service.cli", "worker", "--redis-url", url, "--burst"],
        capture_output=True, timeout=60, check=False,
    )  # fmt: skip
    assert proc.returncode == 2
    assert "cannot reach Redis" in proc.stderr.decode()


def test_unreachable_redis_is_unavailable_and_leaves_no_job(data_dir):
    url = f"redis://127.0.0.1:{_free_port()}/0"  # nothing listens there
    backend, registry = _backend(data_dir, url, "gridplace")
    start = time.monotonic()
    with pytest.raises(UnavailableError, match="unreachable"):
        backend.check_available()
    assert time.monotonic() - start < 10
    route = _route(data_dir, 100, 16)
    with pytest.raises(UnavailableError):
        backend.submit("later", route, ModelParams.parse(trainer="ridge"), None, "key-1")
    assert registry.list_jobs() == []  # the idempotency key is free for the retry
    with pytest.raises(UnavailableError):
        backend.queue_depth()
    backend.close()


def test_job_status_survives_a_redis_outage(data_dir, redis_url):
    """With Redis down, get_job answers from the registry instead of failing."""
    registry = Registry(data_dir)
    job, _ = registry.create_job("m", route=_route(data_dir, 50, 8), params={"n_chunks": 1},
                                 extractor=None, backend="rq")  # fmt: skip
    url = f"redis://127.0.0.1:{_free_port()}/0"
    backend = RQBackend(Settings(data_dir=data_dir, redis_url=url), registry)
    assert backend.get_job(job.id).state == "queued"
    backend.close()

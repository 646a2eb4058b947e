"""The embedded backend end to end: process pool, chunk tasks, registry job state.
Routes are SYNTHETIC (see conftest)."""

from __future__ import annotations

import socket
import subprocess
from pathlib import Path

import numpy as np
import pytest

from service.encoding import ModelParams, build_model
from service.encoding.synthetic import smooth_route
from service.errors import NotFoundError
from service.jobs import TrainingBackend, make_backend
from service.jobs.embedded import EmbeddedBackend
from service.registry import RouteSource
from service.settings import Settings


def test_make_backend_without_redis_is_embedded(backend, data_dir, registry):
    assert isinstance(backend, TrainingBackend)
    made = make_backend(Settings(data_dir=data_dir), registry)
    try:
        assert isinstance(made, EmbeddedBackend)
        made.check_available()
        assert made.queue_depth() >= 0
    finally:
        made.close()


def test_unchunked_job_publishes_and_auto_activates(backend, registry, route_file, wait_done):
    params = ModelParams.parse(trainer="ridge", n_patterns=2)
    job = backend.submit("single", route_file, params, None, None)
    assert job.state == "queued" and job.map == "single"
    done = wait_done(backend, job.id)
    assert done.state == "succeeded", done.error
    assert (done.version, done.chunks_done, done.chunks_total) == (1, 1, 1)
    assert done.started_at is not None and done.finished_at >= done.started_at
    assert {"fit", "evaluate", "publish"} <= set(done.timings)
    info = registry.get_version("single", 1)
    assert info.active and info.job_id == job.id and info.kind == "phase_encoder"
    assert info.params["trainer"] == "ridge"
    m = info.metrics
    assert m["backend"] == "embedded" and m["train_seconds"] > 0
    assert 0.0 <= m["train_precision_at_0"] <= m["train_precision_at_5"] <= 1.0
    assert "fit" in m["stage_seconds"]
    assert info.footprint["paper_bytes"] > 0 and info.artifact_bytes > 0
    assert not (registry.data_dir / "jobs" / job.id).exists()


def test_chunked_job_trains_every_chunk_and_matches_local_training(
    backend, registry, route_file, wait_done
):
    params = ModelParams.parse(trainer="ridge", n_chunks=3, top_chunks=2)
    extractor = {"kind": "patchnorm", "width": 8, "height": 4, "patch": 4}
    job = backend.submit("chunky", route_file, params, extractor, "build-1")
    done = wait_done(backend, job.id)
    assert done.state == "succeeded", done.error
    assert done.chunks_total == 4 and done.chunks_done == 4  # 3 chunk encoders + classifier
    assert {"prepare", "chunk_0", "chunk_1", "chunk_2", "chunk_classifier", "assemble"} <= set(
        done.timings
    )
    info = registry.get_version("chunky", done.version)
    assert info.active and info.kind == "chunked_encoder" and info.extractor == extractor
    assert info.metrics["n_chunks"] == 3
    X = np.load(route_file)
    Q = smooth_route(360, 32, seed=5).query
    local = build_model(params).fit(X)
    served = registry.load_model("chunky", done.version)
    np.testing.assert_array_equal(served.predict(Q), local.predict(Q))

    second = wait_done(backend, backend.submit("chunky", route_file, params, None, None).id)
    assert second.version == 2
    assert registry.get_map("chunky").active_version == 1  # later versions wait for activation


def test_same_idempotency_key_never_trains_twice(backend, registry, route_file, wait_done):
    params = ModelParams.parse(trainer="ridge")
    first = backend.submit("idem", route_file, params, None, "once")
    again = backend.submit("idem", route_file, params, None, "once")
    assert again.id == first.id
    wait_done(backend, first.id)
    after = backend.submit("idem", route_file, params, None, "once")
    assert after.id == first.id and after.state == "succeeded"
    assert registry.get_map("idem").versions == [1]


@pytest.mark.parametrize(
    ("params", "message"),
    [
        ({"code": "mixed_radix", "periods": (5, 5)}, "product of periods"),
        ({"code": "mixed_radix", "n_chunks": 2, "periods": (4, 4)}, "product of periods"),
        ({"periods": (5, 5)}, "product of periods"),  # explicit periods: mixed radix
        ({"code": "residue", "periods": (5, 5)}, "pairwise distinct"),
        ({"code": "residue", "n_chunks": 2, "periods": (4, 5)}, "fewer than"),
        ({"n_chunks": 300}, "too few"),
    ],
)
def test_impossible_parameters_fail_clearly_without_a_version(
    backend, registry, route_file, wait_done, params, message
):
    name = f"bad-{len(registry.list_jobs(limit=1000))}"
    job = backend.submit(name, route_file, ModelParams.parse(trainer="ridge", **params), None, None)
    done = wait_done(backend, job.id)
    assert done.state == "failed" and message in done.error
    assert done.version is None and done.finished_at is not None
    with pytest.raises(NotFoundError):
        registry.get_map(name)
    assert not (registry.data_dir / "jobs" / job.id).exists()


def test_a_missing_route_file_fails_the_job(backend, registry, data_dir, wait_done):
    job = backend.submit("ghost", data_dir / "uploads" / "nope.npy", ModelParams(), None, None)
    done = wait_done(backend, job.id)
    assert done.state == "failed" and "missing" in done.error


def test_unknown_job_is_not_found(backend):
    with pytest.raises(NotFoundError):
        backend.get_job("0" * 32)


def test_job_of_a_dead_server_process_is_failed(backend, registry, route_file):
    dead = subprocess.Popen(["true"])
    dead.wait()
    job, _ = registry.create_job(
        "orphan", route=route_file, params={}, extractor=None, backend="embedded",
        owner=f"{socket.gethostname()}:{dead.pid}",
    )  # fmt: skip
    got = backend.get_job(job.id)
    assert got.state == "failed" and str(dead.pid) in got.error


def test_closed_backend_fails_its_unfinished_jobs(data_dir, registry, route_file):
    b = EmbeddedBackend(Settings(data_dir=data_dir, train_workers=1), registry)
    job = b.submit("closing", route_file, ModelParams.parse(trainer="ridge"), None, None)
    b.close()
    got = registry.get_job(job.id)
    assert got.state in ("failed", "succeeded")  # it may have finished before the shutdown
    if got.state == "failed":
        assert "shut down" in got.error or "died" in got.error
    assert Path(data_dir).exists()


def test_a_job_over_its_time_limit_fails_and_publishes_nothing(data_dir, registry, wait_done):
    path = data_dir / "uploads" / "synthetic-long.npy"
    path.parent.mkdir(parents=True, exist_ok=True)
    np.save(path, smooth_route(2400, 256, seed=9).reference)  # SYNTHETIC; logreg takes seconds
    b = EmbeddedBackend(Settings(data_dir=data_dir, train_workers=1, job_timeout_s=1), registry)
    try:
        job = b.submit("slow", path, ModelParams.parse(trainer="logreg"), None, None)
        done = wait_done(b, job.id, timeout=30)
        assert done.state == "failed" and "time limit of 1 s" in done.error
    finally:
        b.close()  # stops the training process still working on it
    assert registry.version_for_job(job.id) is None
    with pytest.raises(NotFoundError):
        registry.get_map("slow")


def test_a_stuck_job_never_blocks_a_reupload(data_dir, registry, route_file, wait_done):
    """A job of this process left open with no coordinator (one that ended without recording
    its result) is failed when polled or when the same route comes again, which then trains."""
    b = EmbeddedBackend(Settings(data_dir=data_dir, train_workers=1), registry)
    try:
        params = ModelParams.parse(trainer="ridge")
        source = RouteSource(content_sha256="ab" * 32, n_frames=360, n_features=32)
        stuck, created = registry.create_job(  # as if this backend had made it and lost it
            "stuck", route=route_file, params=params.model_dump(mode="json"), extractor=None,
            backend="embedded", owner=b._owner, source=source,
        )  # fmt: skip
        assert created and registry.get_job(stuck.id).state == "queued"
        again = b.submit("stuck", route_file, params, None, None, source=source)
        assert again.id != stuck.id and not again.reused
        failed = registry.get_job(stuck.id)
        assert failed.state == "failed" and "coordinator" in failed.error
        assert wait_done(b, again.id).state == "succeeded"
        lost, _ = registry.create_job(
            "stuck", route=route_file, params={}, extractor=None, backend="embedded",
            owner=b._owner,
        )  # fmt: skip
        assert b.get_job(lost.id).state == "failed"  # polling reconciles it too
    finally:
        b.close()


def test_stopping_the_pool_closes_its_manager_threads_wakeup_before_exit() -> None:
    """The pool's manager thread is joined once its processes are stopped, so its wake-up
    pipe is closed before concurrent.futures' exit hook writes to it (CPython 3.11 races
    there: "OSError: Bad file descriptor" at a graceful shutdown)."""
    import multiprocessing as mp
    import os
    from concurrent.futures import ProcessPoolExecutor

    from service.jobs.embedded import _terminate

    pool = ProcessPoolExecutor(1, mp_context=mp.get_context("forkserver"))
    assert pool.submit(os.getpid).result(timeout=60) != os.getpid()
    manager = pool._executor_manager_thread
    assert manager is not None and manager.is_alive()
    _terminate(pool)
    assert not manager.is_alive()
    assert manager.thread_wakeup._closed  # the exit hook's wakeup() is a no-op now

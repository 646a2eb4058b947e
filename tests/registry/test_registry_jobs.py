"""The registry's job table: idempotency and forward-only state transitions."""

from __future__ import annotations

from pathlib import Path

import pytest

from service.errors import InvalidInputError, NotFoundError
from service.registry import Registry


def _create(registry: Registry, key: str | None = None, name: str = "route-a"):
    return registry.create_job(
        name, route=registry.data_dir / "uploads" / "x.npy", params={"trainer": "ridge"},
        extractor=None, backend="embedded", idempotency_key=key,
    )  # fmt: skip


def test_new_job_is_queued_with_its_spec(registry):
    job, created = _create(registry)
    assert created and job.state == "queued" and job.stage == "queued"
    assert job.chunks_done == 0 and job.version is None and job.error is None
    spec = registry.get_job_spec(job.id)
    assert spec.route == "uploads/x.npy"  # relative to data_dir: portable between hosts
    assert registry.route_path(spec) == registry.data_dir / "uploads" / "x.npy"
    assert spec.params == {"trainer": "ridge"}


def test_same_idempotency_key_returns_the_existing_job(registry):
    first, created = _create(registry, key="k1")
    again, created_again = _create(registry, key="k1")
    assert created and not created_again and again.id == first.id
    other_map, created_other = _create(registry, key="k1", name="route-b")
    assert created_other and other_map.id != first.id
    no_key_1, _ = _create(registry)
    no_key_2, _ = _create(registry)
    assert no_key_1.id != no_key_2.id


def test_bad_inputs(registry):
    with pytest.raises(InvalidInputError):
        _create(registry, key="")
    with pytest.raises(InvalidInputError):
        _create(registry, name="Bad/Name")
    with pytest.raises(NotFoundError):
        registry.get_job("nope")


def test_state_moves_forward_only(registry):
    job, _ = _create(registry)
    assert registry.mark_running(job.id, "chunks", chunks_total=3)
    assert registry.record_progress(job.id, chunks_done_delta=1, timings={"chunk_0": 0.5})
    assert registry.record_progress(job.id, chunks_done_delta=1, timings={"chunk_1": 0.25})
    got = registry.get_job(job.id)
    assert (got.state, got.chunks_done, got.chunks_total) == ("running", 2, 3)
    assert got.timings == {"chunk_0": 0.5, "chunk_1": 0.25} and got.started_at is not None
    assert registry.fail_job(job.id, "chunk 2 failed")
    assert not registry.finish_job(job.id, 1)
    assert not registry.mark_running(job.id, "assemble")
    assert not registry.record_progress(job.id, chunks_done_delta=1)
    got = registry.get_job(job.id)
    assert (got.state, got.error, got.version, got.chunks_done) == ("failed", "chunk 2 failed", None, 2)
    assert got.finished_at is not None


def test_finish_sets_version_and_counts(registry):
    job, _ = _create(registry)
    registry.mark_running(job.id, "fit", chunks_total=1)
    assert registry.finish_job(job.id, 4, {"fit": 1.0})
    got = registry.get_job(job.id)
    assert (got.state, got.version, got.chunks_done, got.stage) == ("succeeded", 4, 1, "done")
    assert not registry.fail_job(job.id, "late failure")
    assert registry.get_job(job.id).state == "succeeded"


def test_listing_and_counting(registry, tmp_path: Path):
    a, _ = _create(registry)
    b, _ = _create(registry, name="route-b")
    registry.fail_job(b.id, "x")
    assert registry.count_jobs(["queued"]) == 1
    assert registry.count_jobs(["queued", "failed"], backend="embedded") == 2
    assert [j.id for j in registry.list_jobs(map_name="route-a")] == [a.id]
    assert registry.job_owners("embedded") == [(a.id, None)]


def test_a_job_whose_version_is_published_never_reads_failed(registry):
    from service.encoding import ModelParams, build_model
    from service.encoding.synthetic import smooth_route

    job, _ = _create(registry)
    registry.mark_running(job.id, "publish", chunks_total=1)
    model = build_model(ModelParams.parse(trainer="ridge")).fit(smooth_route(60, 8).reference)
    v = registry.publish("route-a", model, params={}, extractor=None, metrics={}, job_id=job.id)
    # the process died before recording success; the reaper calls fail_job
    assert not registry.fail_job(job.id, "worker lost")
    got = registry.get_job(job.id)
    assert (got.state, got.version, got.error) == ("succeeded", v.version, None)


def test_a_failed_job_cannot_publish(registry):
    from service.encoding import ModelParams, build_model
    from service.encoding.synthetic import smooth_route
    from service.errors import ConflictError

    job, _ = _create(registry)
    registry.fail_job(job.id, "timed out")
    model = build_model(ModelParams.parse(trainer="ridge")).fit(smooth_route(60, 8).reference)
    with pytest.raises(ConflictError, match="has failed"):
        registry.publish("route-a", model, params={}, extractor=None, metrics={}, job_id=job.id)
    with pytest.raises(NotFoundError):
        registry.get_map("route-a")
    assert not any((registry.data_dir / "artifacts" / "route-a").glob("v*"))

"""The registry's job table: idempotency and forward-only state transitions."""

from __future__ import annotations

from pathlib import Path

import pytest

from service.errors import InvalidInputError, NotFoundError
from service.registry import Registry, RouteSource
from service.registry.job_cursor import encode_cursor


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


def _source(sha: str = "a" * 64, d: int = 8) -> RouteSource:
    return RouteSource(content_sha256=sha, n_frames=60, n_features=d)


def _create_from(registry: Registry, source: RouteSource, params: dict | None = None,
                 force: bool = False, name: str = "route-a"):  # fmt: skip
    return registry.create_job(
        name, route=registry.data_dir / "uploads" / "x.npy", params=params or {"rho": 0.5},
        extractor=None, backend="embedded", source=source, force=force,
    )  # fmt: skip


def test_a_repeated_upload_is_the_existing_job_unless_forced(registry):
    first, created = _create_from(registry, _source())
    again, created_again = _create_from(registry, _source())
    assert created and not created_again and again.id == first.id
    assert first.content_sha256 == "a" * 64
    other_params, c1 = _create_from(registry, _source(), params={"rho": 0.25})
    other_data, c2 = _create_from(registry, _source("b" * 64))
    other_map, c3 = _create_from(registry, _source(), name="route-b")
    assert c1 and c2 and c3 and len({first.id, other_params.id, other_data.id, other_map.id}) == 4
    forced, c4 = _create_from(registry, _source(), force=True)
    assert c4 and forced.id != first.id


def test_a_repeat_of_a_failed_job_trains_again_and_of_a_deleted_version_too(registry):
    from service.encoding import ModelParams, build_model
    from service.encoding.synthetic import smooth_route

    failed, _ = _create_from(registry, _source())
    registry.fail_job(failed.id, "boom")
    retry, created = _create_from(registry, _source())
    assert created and retry.id != failed.id
    model = build_model(ModelParams.parse(trainer="ridge")).fit(smooth_route(60, 8).reference)
    v = registry.publish("route-a", model, params={}, extractor=None, metrics={}, job_id=retry.id)
    registry.finish_job(retry.id, v.version)
    same, created = _create_from(registry, _source())
    assert not created and same.id == retry.id and same.version == v.version
    v2 = registry.publish("route-a", model, params={}, extractor=None, metrics={})
    registry.activate("route-a", v2.version)
    registry.delete_version("route-a", v.version)
    fresh, created = _create_from(registry, _source())
    assert created and fresh.id != retry.id


def test_progress_counts_each_part_once_and_retries_are_recorded(registry):
    job, _ = _create(registry)
    registry.mark_running(job.id, "chunks", chunks_total=3)
    assert registry.record_progress(job.id, chunks_done_delta=1, part="chunk-0")
    assert registry.record_retry(job.id, "chunk-1", 1, "its worker stopped sending heartbeats")
    assert registry.record_progress(job.id, chunks_done_delta=1, part="chunk-1")
    assert registry.record_progress(job.id, chunks_done_delta=1, part="chunk-1")  # a 2nd run
    got = registry.get_job(job.id)
    assert got.chunks_done == 2 and registry.parts_done(job.id) == {"chunk-0", "chunk-1"}
    assert [(r.part, r.attempt) for r in got.retries] == [("chunk-1", 1)]
    assert "heartbeats" in got.retries[0].error and got.retries[0].at is not None
    registry.fail_job(job.id, "x")
    assert not registry.record_retry(job.id, "chunk-2", 1, "late")


def test_jobs_are_listed_newest_first_in_pages(registry):
    ids = [_create(registry, name="route-a" if i % 2 else "route-b")[0].id for i in range(7)]
    registry.fail_job(ids[0], "x")
    seen, cursor = [], None
    while True:
        page = registry.list_jobs(limit=3, after=cursor)
        seen += [j.id for j in page]
        if len(page) < 3:
            break
        cursor = encode_cursor(page[-1])
    assert seen == ids[::-1]
    assert [j.id for j in registry.list_jobs(map_name="route-a")] == ids[1::2][::-1]
    assert [j.id for j in registry.list_jobs(states=["failed"])] == [ids[0]]
    with pytest.raises(InvalidInputError, match="cursor"):
        registry.list_jobs(after="not-a-cursor")


def test_a_new_version_of_another_width_needs_allow_dimension_change(registry):
    from service.encoding import ModelParams, build_model
    from service.encoding.synthetic import smooth_route
    from service.errors import DimensionChangeError

    def fit(d: int):
        return build_model(ModelParams.parse(trainer="ridge")).fit(smooth_route(60, d).reference)

    narrow, wide = fit(8), fit(12)
    registry.publish("route-a", narrow, params={}, extractor=None, metrics={})
    with pytest.raises(DimensionChangeError, match="d=8 .* d=12") as info:
        registry.publish("route-a", wide, params={}, extractor=None, metrics={})
    assert info.value.http_status == 409 and info.value.details["expected"] == 8
    assert registry.get_map("route-a").versions == [1]  # nothing published, no orphan
    assert registry.check_width("route-a", 8, False) is None
    v2 = registry.publish("route-a", wide, params={}, extractor=None, metrics={},
                          allow_dimension_change=True)  # fmt: skip
    assert v2.extra["dimension_change"] == {"from": 8, "to": 12, "reference_version": 1}
    # the reference is the ACTIVE version (v1, d=8) while v2 is not activated
    assert registry.reference_width("route-a") == (1, 8)

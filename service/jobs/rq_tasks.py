"""What RQ workers execute: the pipeline steps, one RQ job each, and the failure callback.

A gridplace job becomes several RQ jobs with deterministic ids (``gridplace-<job>-<part>``):
``prepare``; then ``chunk-<c>`` for every chunk and ``classifier``, all depending on
``prepare`` and free to run on different workers; then ``assemble``, depending on all of
them, so RQ starts it only when every part succeeded. Any part that fails — by an exception,
a timeout, or its worker dying (RQ's abandoned-job cleanup) — runs :func:`on_part_failure`,
which fails the gridplace job and cancels the parts still waiting: no version appears.
An unchunked route is the single part ``train``.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

from redis import Redis
from redis.exceptions import RedisError
from rq.job import Job, JobStatus
from rq.serializers import JSONSerializer

from service.jobs import pipeline
from service.jobs.workspace import Workspace

log = logging.getLogger(__name__)
SERIALIZER = JSONSerializer  # job data in Redis is JSON: nothing there is ever unpickled
_WAITING = {JobStatus.QUEUED, JobStatus.DEFERRED, JobStatus.SCHEDULED}


def part_ids(job_id: str, n_chunks: int) -> dict[str, str]:
    """RQ job id of every part of gridplace job ``job_id``."""
    if n_chunks == 1:
        parts = ["train"]
    else:
        parts = ["prepare", *(f"chunk-{c}" for c in range(n_chunks)), "classifier", "assemble"]
    return {part: f"gridplace-{job_id}-{part}" for part in parts}


def _skipping(exc: pipeline.JobFinished) -> dict[str, Any]:
    log.info("%s", exc.message)
    return {"skipped": exc.message}


def train(data_dir: str, job_id: str) -> dict[str, Any]:
    try:
        return {"version": pipeline.train_single(Path(data_dir), job_id)}
    except pipeline.JobFinished as exc:
        return _skipping(exc)


def prepare(data_dir: str, job_id: str) -> dict[str, Any]:
    try:
        return pipeline.prepare(Path(data_dir), job_id)
    except pipeline.JobFinished as exc:
        return _skipping(exc)


def train_chunk(data_dir: str, job_id: str, chunk: int) -> dict[str, Any]:
    try:
        return {"chunk": chunk, "seconds": pipeline.train_chunk(Path(data_dir), job_id, chunk)}
    except pipeline.JobFinished as exc:
        return _skipping(exc)


def train_classifier(data_dir: str, job_id: str) -> dict[str, Any]:
    try:
        return {"seconds": pipeline.train_classifier(Path(data_dir), job_id)}
    except pipeline.JobFinished as exc:
        return _skipping(exc)


def assemble(data_dir: str, job_id: str) -> dict[str, Any]:
    try:
        return {"version": pipeline.assemble(Path(data_dir), job_id)}
    except pipeline.JobFinished as exc:
        return _skipping(exc)


def part_name(rq_job_id: str, job_id: str) -> str:
    return rq_job_id.removeprefix(f"gridplace-{job_id}-")


def on_part_failure(
    job: Job, connection: Redis, exc_type: type[BaseException] | None, exc_value: Any, tb: Any
) -> None:
    """RQ failure callback (worker, or whoever runs the abandoned-job cleanup)."""
    data_dir, job_id = str(job.args[0]), str(job.args[1])
    part = part_name(job.id, job_id)
    if exc_type is not None and exc_type.__name__ == "AbandonedJobError":
        reason = "its worker stopped sending heartbeats (worker killed or host lost)"
    elif isinstance(exc_value, BaseException):
        reason = pipeline.describe(exc_value)
    else:
        reason = str(exc_value or exc_type)
    fail_job(Path(data_dir), job_id, f"{part} failed: {reason}", connection)


def fail_job(data_dir: Path, job_id: str, message: str, connection: Redis) -> None:
    """Cancel the job's waiting parts, fail it and drop its intermediate files (in this
    order: once a job reads ``failed``, none of its parts is still queued)."""
    registry = pipeline.registry_for(str(data_dir))
    if registry.get_job(job_id).done:
        return
    spec = registry.get_job_spec(job_id)
    cancel_waiting_parts(connection, job_id, int(spec.params.get("n_chunks", 1)))
    if registry.fail_job(job_id, message):
        log.warning("training job %s failed: %s", job_id, message)
        Workspace(data_dir, job_id).remove()


def cancel_waiting_parts(connection: Redis, job_id: str, n_chunks: int) -> None:
    """Cancel the parts that have not started (best effort: the job is failed anyway)."""
    ids = list(part_ids(job_id, n_chunks).values())
    try:
        parts = Job.fetch_many(ids, connection=connection, serializer=SERIALIZER)
        for part in parts:
            if part is not None and part.get_status(refresh=False) in _WAITING:
                part.cancel()
    except RedisError as exc:
        log.warning("could not cancel the waiting parts of job %s: %s", job_id, exc)

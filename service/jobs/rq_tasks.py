"""What RQ workers execute: the pipeline steps, one RQ job each, and the failure callback.

A gridplace job becomes several RQ jobs with deterministic ids (``gridplace-<job>-<part>``):
``prepare``; then ``chunk-<c>`` for every chunk and ``classifier``, all depending on
``prepare`` and free to run on different workers; then ``assemble``, depending on all of
them, so RQ starts it only when every part succeeded. An unchunked route is the single part
``train``.

Every part is enqueued with a bounded RQ retry (``settings.job_retries``, exponential backoff
from ``settings.job_retry_backoff_s``): a part whose worker died (RQ's abandoned-job cleanup),
whose training process was killed, or that raised an unexpected error runs again, and the
retry is recorded on the gridplace job. A part that fails on bad input (a 4xx error: the
route cannot fit the parameters) is not retried. Only a part that fails its last attempt
fails the gridplace job — :func:`on_part_failure` cancels the parts still waiting, so no
version appears. Parts write their outputs idempotently (see :mod:`service.jobs.workspace`),
so a second run of a part whose first run finished but was not recorded changes nothing.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

from redis import Redis
from redis.exceptions import ConnectionError as RedisConnectionError
from redis.exceptions import RedisError
from redis.exceptions import TimeoutError as RedisTimeoutError
from rq import Queue
from rq.job import Job, JobStatus
from rq.registry import ScheduledJobRegistry
from rq.serializers import JSONSerializer
from rq.utils import current_timestamp

from service.errors import GridplaceError
from service.jobs import pipeline
from service.jobs.workspace import Workspace

log = logging.getLogger(__name__)
SERIALIZER = JSONSerializer  # job data in Redis is JSON: nothing there is ever unpickled
_WAITING = {JobStatus.QUEUED, JobStatus.DEFERRED, JobStatus.SCHEDULED}
RETRIES_META = "gridplace_retries"  # the part's retry budget, kept in the RQ job's meta
PROMOTE_LOCK_MS = 900
REDIS_DOWN: tuple[type[Exception], ...] = (RedisConnectionError, RedisTimeoutError)


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


def _permanent(exc_value: Any) -> bool:
    """Bad input (a 4xx error) fails the same way every time: not worth a retry."""
    return isinstance(exc_value, GridplaceError) and exc_value.http_status < 500


def on_part_failure(
    job: Job, connection: Redis, exc_type: type[BaseException] | None, exc_value: Any, tb: Any
) -> None:
    """RQ failure callback (worker, or whoever runs the abandoned-job cleanup).

    RQ calls it on every failed attempt and, right after it returns, queues the part again
    if ``job.retries_left`` is positive: a retry is recorded on the gridplace job; the last
    failed attempt (or one on bad input, whose retries are cancelled here) fails it."""
    data_dir, job_id = str(job.args[0]), str(job.args[1])
    part = part_name(job.id, job_id)
    if exc_type is not None and exc_type.__name__ == "AbandonedJobError":
        reason = "its worker stopped sending heartbeats (worker killed or host lost)"
    elif isinstance(exc_value, BaseException):
        reason = pipeline.describe(exc_value)
    else:
        reason = str(exc_value or exc_type)
    registry = pipeline.registry_for(data_dir)
    if isinstance(exc_value, REDIS_DOWN):
        # RQ's own bookkeeping lost Redis (the part itself may have finished): the job is
        # reconciled by each part's state once Redis answers again
        log.warning("%s of job %s: Redis unreachable (%s); leaving it to reconciliation",
                    part, job_id, reason)  # fmt: skip
        return
    if _permanent(exc_value):
        job.retries_left = 0
    if job.retries_left:
        budget = int((job.meta or {}).get(RETRIES_META, job.retries_left))
        attempt = budget - int(job.retries_left) + 1
        if registry.record_retry(job_id, part, attempt, reason):
            log.warning("%s of job %s failed on attempt %d (%s); retrying", part, job_id,
                        attempt, reason)  # fmt: skip
        return
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


def promote_due_retries(queue: Queue, holder: str) -> int:
    """Queue the parts whose retry backoff has passed; returns how many. Runs in every
    worker (and the server's reconciler) under a short Redis lock, so a due retry moves
    within about a second whichever process is alive — unlike RQ's scheduler, whose lock
    outlives a killed worker by a minute."""
    conn = queue.connection
    if not conn.set(f"gridplace:promote:{queue.name}", holder, nx=True, px=PROMOTE_LOCK_MS):
        return 0
    registry = ScheduledJobRegistry(queue=queue)
    job_ids = registry.get_jobs_to_schedule(current_timestamp())
    if not job_ids:
        return 0
    jobs = Job.fetch_many(job_ids, connection=conn, serializer=SERIALIZER)
    with conn.pipeline() as pipe:
        for job in jobs:
            if job is not None:
                queue._enqueue_job(job, pipeline=pipe)  # what RQ's scheduler does
        for job_id in job_ids:
            registry.remove(job_id, pipeline=pipe)
        pipe.execute()
    return sum(j is not None for j in jobs)


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

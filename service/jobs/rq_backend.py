"""Training on RQ workers (``gridplace worker``, any number, on hosts sharing ``data_dir``).

Submitting records the job in the registry and enqueues its parts (see
:mod:`service.jobs.rq_tasks`); workers record progress in the registry as parts finish.
:meth:`RQBackend.get_job` also reconciles with Redis: it runs RQ's abandoned-job cleanup
(so a job whose worker was killed fails without waiting for another worker's maintenance)
and fails a job whose parts failed or vanished from Redis.
"""

from __future__ import annotations

import logging
from datetime import timedelta
from pathlib import Path
from typing import Any

from redis import Redis
from redis.exceptions import RedisError
from rq import Callback, Queue
from rq.job import Job, JobStatus
from rq.registry import DeferredJobRegistry, StartedJobRegistry
from rq.timeouts import TimerDeathPenalty

from service.encoding import ModelParams
from service.errors import UnavailableError
from service.jobs import rq_tasks
from service.jobs.pipeline import describe
from service.registry import JobInfo, Registry
from service.registry.db import utcnow
from service.settings import Settings

log = logging.getLogger(__name__)
BACKEND = "rq"
SOCKET_TIMEOUT_S = 2.0
RESULT_TTL_S = 24 * 3600
FAILURE_TTL_S = 7 * 24 * 3600
LOST_AFTER = timedelta(seconds=60)  # parts missing from Redis this long after submit: lost
_FAILED = {JobStatus.FAILED, JobStatus.STOPPED, JobStatus.CANCELED}


class RQBackend:
    def __init__(self, settings: Settings, registry: Registry) -> None:
        if not settings.redis_url:
            raise UnavailableError("the RQ backend needs settings.redis_url")
        self._settings = settings
        self._registry = registry
        self._data_dir = str(registry.data_dir.resolve())
        self._redis = Redis.from_url(
            settings.redis_url, socket_timeout=SOCKET_TIMEOUT_S,
            socket_connect_timeout=SOCKET_TIMEOUT_S,
        )  # fmt: skip
        self.queue = Queue(settings.queue_name, connection=self._redis,
                           serializer=rq_tasks.SERIALIZER)  # fmt: skip

    # -- TrainingBackend ------------------------------------------------------------------
    def check_available(self) -> None:
        try:
            self._redis.ping()
        except RedisError as exc:
            raise self._unavailable(exc) from exc

    def submit(
        self,
        map_name: str,
        route: Path,
        params: ModelParams,
        extractor: dict[str, Any] | None,
        idempotency_key: str | None,
    ) -> JobInfo:
        job, created = self._registry.create_job(
            map_name, route=route, params=params.model_dump(mode="json"), extractor=extractor,
            backend=BACKEND, idempotency_key=idempotency_key,
        )  # fmt: skip
        if not created:
            return job
        try:
            self._enqueue(job.id, params.n_chunks)
        except RedisError as exc:
            self._registry.discard_queued_job(job.id)  # the key stays free for a retry
            rq_tasks.cancel_waiting_parts(self._redis, job.id, params.n_chunks)
            raise self._unavailable(exc) from exc
        return job

    def get_job(self, job_id: str) -> JobInfo:
        job = self._registry.get_job(job_id)
        if job.done:
            return job
        spec = self._registry.get_job_spec(job_id)
        if spec.backend != BACKEND:
            return job
        try:
            self._reconcile(job, int(spec.params.get("n_chunks", 1)))
        except RedisError as exc:  # Redis down: report what the registry knows
            log.warning("cannot reconcile job %s with Redis: %s", job_id, exc)
        return self._registry.get_job(job_id)

    def queue_depth(self) -> int:
        try:
            return int(self.queue.count + DeferredJobRegistry(queue=self.queue).count)
        except RedisError as exc:
            raise self._unavailable(exc) from exc

    def close(self) -> None:
        self._redis.close()

    # -- internals ------------------------------------------------------------------------
    def _enqueue(self, job_id: str, n_chunks: int) -> None:
        ids = rq_tasks.part_ids(job_id, n_chunks)
        common: dict[str, Any] = {
            "job_timeout": self._settings.job_timeout_s,
            "result_ttl": RESULT_TTL_S,
            "failure_ttl": FAILURE_TTL_S,
            "on_failure": Callback(rq_tasks.on_part_failure),
            "description": f"gridplace training job {job_id}",
        }
        args = (self._data_dir, job_id)
        q = self.queue
        if n_chunks == 1:
            q.enqueue(rq_tasks.train, *args, job_id=ids["train"], **common)
            return
        prep = q.enqueue(rq_tasks.prepare, *args, job_id=ids["prepare"], **common)
        parts = [
            q.enqueue(
                rq_tasks.train_chunk, *args, c, job_id=ids[f"chunk-{c}"], depends_on=prep, **common
            )
            for c in range(n_chunks)
        ]
        parts.append(
            q.enqueue(rq_tasks.train_classifier, *args, job_id=ids["classifier"],
                      depends_on=prep, **common)
        )  # fmt: skip
        q.enqueue(rq_tasks.assemble, *args, job_id=ids["assemble"], depends_on=parts, **common)

    def _reconcile(self, job: JobInfo, n_chunks: int) -> None:
        # moves parts of dead workers to the failed registry and runs their failure callback
        StartedJobRegistry(queue=self.queue, death_penalty_class=TimerDeathPenalty).cleanup()
        ids = list(rq_tasks.part_ids(job.id, n_chunks).values())
        parts = Job.fetch_many(ids, connection=self._redis, serializer=rq_tasks.SERIALIZER)
        for rq_id, part in zip(ids, parts, strict=True):
            if part is None:
                continue
            status = part.get_status(refresh=False)
            if status in _FAILED:
                rq_tasks.fail_job(Path(self._data_dir), job.id,
                                  f"{rq_tasks.part_name(rq_id, job.id)} {status}: "
                                  f"{self._failure_text(part)}", self._redis)  # fmt: skip
                return
        if all(p is None for p in parts) and utcnow() - job.created_at > LOST_AFTER:
            rq_tasks.fail_job(Path(self._data_dir), job.id,
                              "the queue no longer knows this job (Redis restarted or flushed?)",
                              self._redis)  # fmt: skip

    @staticmethod
    def _failure_text(part: Job) -> str:
        try:
            result = part.latest_result()
        except Exception:  # noqa: BLE001 - an unreadable result must not hide the failure
            result = None
        text = (getattr(result, "exc_string", None) or "").strip()
        return text.splitlines()[-1] if text else "no error recorded"

    def _unavailable(self, exc: Exception) -> UnavailableError:
        kw = self._redis.connection_pool.connection_kwargs
        where = kw.get("path") or f"{kw.get('host')}:{kw.get('port')}"
        return UnavailableError(
            f"the training queue (Redis at {where}) is unreachable: {describe(exc)}",
            redis=str(where),
        )

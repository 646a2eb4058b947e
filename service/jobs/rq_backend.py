"""Training on RQ workers (``gridplace worker``, any number, on hosts sharing ``data_dir``).

Submitting records the job in the registry and enqueues its parts (see
:mod:`service.jobs.rq_tasks`) with a bounded retry; workers record progress in the registry
as parts finish. Reconciliation with Redis — on every :meth:`RQBackend.get_job` of an open
job, and for every open job every ``reconcile_interval_s`` in a background thread — runs
RQ's abandoned-job cleanup (a part of a killed worker is retried, or fails the job once its
retries are spent, without waiting for another worker's maintenance) and then judges each
part by its own state: a part finished (in the registry) is done whatever Redis says; a
part queued, scheduled for a retry, running, or waiting on parts that can still finish can
finish; a part that failed, vanished from Redis (restarted or flushed) or waits on a part
that will never finish cannot, and then the job fails with that reason. So a job in flight
during a Redis restart fails within one reconcile interval instead of staying ``running``.
"""

from __future__ import annotations

import logging
import threading
from datetime import timedelta
from pathlib import Path
from typing import Any

from redis import Redis
from redis.exceptions import RedisError
from rq import Callback, Queue, Retry
from rq.job import Job, JobStatus
from rq.registry import DeferredJobRegistry, StartedJobRegistry
from rq.timeouts import TimerDeathPenalty

from service.encoding import ModelParams
from service.errors import GridplaceError, UnavailableError
from service.jobs import rq_tasks
from service.jobs.pipeline import describe, use_registry
from service.jobs.workspace import sweep_workspaces
from service.registry import JobInfo, Registry, RouteSource
from service.registry.db import utcnow
from service.settings import Settings

log = logging.getLogger(__name__)
BACKEND = "rq"
SOCKET_TIMEOUT_S = 2.0
RESULT_TTL_S = 24 * 3600
FAILURE_TTL_S = 7 * 24 * 3600
LOST_AFTER = timedelta(seconds=15)  # a part missing from Redis this long after submit: lost
_FAILED = {JobStatus.FAILED, JobStatus.STOPPED, JobStatus.CANCELED}
_ALIVE = {JobStatus.QUEUED, JobStatus.SCHEDULED, JobStatus.STARTED, JobStatus.CREATED}


class RQBackend:
    def __init__(self, settings: Settings, registry: Registry) -> None:
        if not settings.redis_url:
            raise UnavailableError("the RQ backend needs settings.redis_url")
        self._settings = settings
        self._registry = registry
        self._data_dir = str(registry.data_dir.resolve())
        use_registry(registry)  # failure callbacks run here (reconciliation) use it too
        self._redis = Redis.from_url(
            settings.redis_url, socket_timeout=SOCKET_TIMEOUT_S,
            socket_connect_timeout=SOCKET_TIMEOUT_S,
        )  # fmt: skip
        self.queue = Queue(settings.queue_name, connection=self._redis,
                           serializer=rq_tasks.SERIALIZER)  # fmt: skip
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        if settings.reconcile_interval_s > 0:
            self._thread = threading.Thread(target=self._reconcile_loop, daemon=True,
                                            name="gridplace-rq-reconcile")  # fmt: skip
            self._thread.start()

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
        *,
        source: RouteSource | None = None,
        force: bool = False,
    ) -> JobInfo:
        job, created = self._registry.create_job(
            map_name, route=route, params=params.model_dump(mode="json"), extractor=extractor,
            backend=BACKEND, idempotency_key=idempotency_key, source=source, force=force,
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
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=10)
            self._thread = None
        self._redis.close()

    def reconcile_all(self) -> int:
        """Reconcile every open job of this backend with Redis; returns how many failed."""
        failed = 0
        for job_id, _ in self._registry.job_owners(BACKEND):
            before = self._registry.get_job(job_id)
            if self.get_job(job_id).state == "failed" and before.state != "failed":
                failed += 1
        return failed

    # -- internals ------------------------------------------------------------------------
    def _reconcile_loop(self) -> None:
        interval = self._settings.reconcile_interval_s
        while not self._stop.wait(interval):
            try:
                rq_tasks.promote_due_retries(self.queue, f"server-{id(self)}")
                self.reconcile_all()
                sweep_workspaces(self._registry)
            except (RedisError, GridplaceError) as exc:  # Redis or the registry is down
                log.warning("reconciling training jobs failed: %s", describe(exc))
            except Exception:  # the loop must survive anything
                log.exception("reconciling training jobs failed")

    def _retry(self) -> Retry | None:
        n = self._settings.job_retries
        if n == 0:
            return None
        backoff = self._settings.job_retry_backoff_s
        return Retry(max=n, interval=[backoff * 2**i for i in range(n)])

    def _enqueue(self, job_id: str, n_chunks: int) -> None:
        ids = rq_tasks.part_ids(job_id, n_chunks)
        common: dict[str, Any] = {
            "job_timeout": self._settings.job_timeout_s,
            "result_ttl": RESULT_TTL_S,
            "failure_ttl": FAILURE_TTL_S,
            "on_failure": Callback(rq_tasks.on_part_failure),
            "description": f"gridplace training job {job_id}",
            "retry": self._retry(),
            "meta": {rq_tasks.RETRIES_META: self._settings.job_retries},
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
        # parts of dead workers: retried, or moved to the failed registry (running our
        # failure callback) once their retries are spent
        StartedJobRegistry(queue=self.queue, death_penalty_class=TimerDeathPenalty).cleanup()
        ids = rq_tasks.part_ids(job.id, n_chunks)
        fetched = Job.fetch_many(list(ids.values()), connection=self._redis,
                                 serializer=rq_tasks.SERIALIZER)  # fmt: skip
        parts = dict(zip(ids, fetched, strict=True))
        done = self._registry.parts_done(job.id)
        settled = utcnow() - job.created_at > LOST_AFTER  # every part was enqueued by then
        for part, rq_job in parts.items():
            if part in done:
                continue
            reason = self._cannot_finish(part, rq_job, parts, done, settled)
            if reason is not None:
                rq_tasks.fail_job(Path(self._data_dir), job.id, f"{part} {reason}", self._redis)
                return

    def _cannot_finish(
        self, part: str, rq_job: Job | None, parts: dict[str, Job | None], done: set[str],
        settled: bool,
    ) -> str | None:  # fmt: skip
        """Why ``part`` (not finished in the registry) can never finish; None if it can."""
        if rq_job is None:
            return ("is no longer known to the queue (Redis restarted or flushed?); the job "
                    "cannot finish") if settled else None  # fmt: skip
        status = rq_job.get_status(refresh=False)
        if status == JobStatus.CANCELED and any(
            p is not None and p.get_status(refresh=False) == JobStatus.STARTED
            for p in parts.values()
        ):  # cancelled by a failing part whose callback is failing the job right now
            return None
        if status in _FAILED:
            return f"{getattr(status, 'value', status)}: {self._failure_text(rq_job)}"
        if status in _ALIVE or status == JobStatus.FINISHED:
            return None
        # deferred: RQ starts it only when every dependency FINISHED in Redis
        for dep in _dependencies(part, parts):
            dep_job = parts[dep]
            if dep_job is None:
                if settled:
                    return f"waits on {dep}, which the queue no longer knows; the job cannot finish"
                continue
            dep_status = dep_job.get_status(refresh=False)
            if dep_status in _FAILED and dep in done:  # its work is there, its record is not
                return (f"waits on {dep}, which finished but is {dep_status.value} in the queue "
                        "(Redis outage?); the job cannot finish")  # fmt: skip
        return None

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


def _dependencies(part: str, parts: dict[str, Job | None]) -> list[str]:
    if part == "assemble":
        return [p for p in parts if p.startswith("chunk-") or p == "classifier"]
    if part.startswith("chunk-") or part == "classifier":
        return ["prepare"]
    return []

"""The RQ worker that ``gridplace worker`` runs.

RQ keeps a running job in the queue's started-job registry until ``heartbeat TTL`` after the
worker's last heartbeat; a worker that dies (SIGKILL, lost host) stops heart-beating and its
job is moved to the failed registry — running our failure callback — once that TTL passed.
RQ hard-codes a 60 s grace on top of the monitoring interval; :class:`GridplaceWorker` makes
it configurable, so a dead worker is noticed in ``monitoring interval + grace`` seconds.

A busy worker also rides out a Redis outage: RQ lets a connection error from the heartbeat
in its horse-monitoring loop (or from the bookkeeping after the horse exits) escape and end
the worker. :class:`GridplaceWorker` logs the outage, keeps waiting for its training process,
retries Redis with exponential backoff until it answers, logs the recovery and goes back to
work; what happened to the part meanwhile is settled by the server's reconciliation.
A thread of every worker queues parts again once their retry backoff has passed
(:func:`~service.jobs.rq_tasks.promote_due_retries`).
"""

from __future__ import annotations

import logging
import os
import threading
import time
from typing import Any

from redis import Redis
from redis.exceptions import RedisError
from rq import Queue, Worker
from rq.job import Job

from service.errors import UnavailableError
from service.jobs import rq_tasks
from service.jobs.rq_tasks import REDIS_DOWN, promote_due_retries

log = logging.getLogger("gridplace.worker")

DEFAULT_MONITORING_INTERVAL_S = 10
DEFAULT_HEARTBEAT_GRACE_S = 30
DEFAULT_MAINTENANCE_INTERVAL_S = 60
REDIS_BACKOFF_S = (0.5, 30.0)  # first and longest wait between reconnection attempts
PROMOTE_INTERVAL_S = 1.0


class GridplaceWorker(Worker):
    """An RQ :class:`~rq.Worker` with a configurable heartbeat grace period."""

    heartbeat_grace_s: int = DEFAULT_HEARTBEAT_GRACE_S
    _redis_down_since: float | None = None

    def get_heartbeat_ttl(self, job: Job) -> int:
        interval = float(self.job_monitoring_interval)
        if job.timeout and job.timeout > 0:
            interval = max(1.0, min(job.timeout - self.current_job_working_time, interval))
        return int(interval) + int(self.heartbeat_grace_s)

    def maintain_heartbeats(self, job: Job) -> None:
        """Called every monitoring interval while the work horse trains: an outage only
        skips heartbeats (the horse keeps training); the next interval tries again."""
        try:
            super().maintain_heartbeats(job)
        except REDIS_DOWN as exc:
            self._lost(exc, f"while running {job.id}")
            return
        self._back()

    def execute_job(self, job: Job, queue: Queue) -> None:
        try:
            super().execute_job(job, queue)
        except REDIS_DOWN as exc:  # recording the horse's outcome needs Redis
            self._lost(exc, f"after running {job.id}")
            self._wait_for_redis()

    def _lost(self, exc: BaseException, when: str) -> None:
        if self._redis_down_since is None:
            self._redis_down_since = time.monotonic()
            log.warning("worker %s: Redis unreachable %s (%s); riding it out", self.name,
                        when, exc)  # fmt: skip

    def _back(self) -> None:
        if self._redis_down_since is not None:
            log.warning("worker %s: Redis reachable again after %.1f s", self.name,
                        time.monotonic() - self._redis_down_since)  # fmt: skip
            self._redis_down_since = None

    def _wait_for_redis(self) -> None:
        wait, longest = REDIS_BACKOFF_S
        while True:
            try:
                self.connection.ping()
            except REDIS_DOWN:
                time.sleep(wait)
                wait = min(wait * 2, longest)
                continue
            self._back()
            return


def _horse_killed(job: Job, pid: int, status: int, rusage: Any) -> None:
    """RQ marks a job whose work horse died (OOM killer, SIGKILL) failed without running its
    failure callback; fail the gridplace job here instead of waiting for a poll."""
    signal_note = f" by signal {os.WTERMSIG(status)}" if os.WIFSIGNALED(status) else ""
    rq_tasks.on_part_failure(
        job, job.connection, RuntimeError,
        RuntimeError(f"its training process {pid} was killed{signal_note} (out of memory?)"),
        None,
    )  # fmt: skip


class _RetryPromoter(threading.Thread):
    """Moves due retries from the scheduled registry to the queue, every second, on its own
    Redis connection (the work horses forked meanwhile never touch it)."""

    def __init__(self, redis_url: str, queue_name: str, holder: str) -> None:
        super().__init__(name="gridplace-retry-promoter", daemon=True)
        self._redis = Redis.from_url(redis_url, socket_connect_timeout=2, socket_timeout=2)
        self._queue = Queue(queue_name, connection=self._redis, serializer=rq_tasks.SERIALIZER)
        self._holder = holder
        self.stop = threading.Event()

    def run(self) -> None:
        while not self.stop.wait(PROMOTE_INTERVAL_S):
            try:
                promote_due_retries(self._queue, self._holder)
            except RedisError:  # an outage: the worker logs it; try again next second
                continue
        self._redis.close()


def run_worker(
    redis_url: str,
    queue_name: str,
    *,
    burst: bool = False,
    name: str | None = None,
    monitoring_interval_s: int = DEFAULT_MONITORING_INTERVAL_S,
    heartbeat_grace_s: int = DEFAULT_HEARTBEAT_GRACE_S,
    maintenance_interval_s: int = DEFAULT_MAINTENANCE_INTERVAL_S,
    log_level: str = "INFO",
) -> bool:
    """Work on ``queue_name`` until stopped (or, with ``burst``, until it is empty)."""
    connection = Redis.from_url(redis_url, socket_connect_timeout=5, health_check_interval=30)
    try:
        connection.ping()
    except RedisError as exc:
        kw = connection.connection_pool.connection_kwargs
        where = kw.get("path") or f"{kw.get('host')}:{kw.get('port')}"
        raise UnavailableError(f"cannot reach Redis at {where}: {exc}", redis=str(where)) from exc
    queue = Queue(queue_name, connection=connection, serializer=rq_tasks.SERIALIZER)
    worker = GridplaceWorker(
        [queue],
        connection=connection,
        name=name,
        serializer=rq_tasks.SERIALIZER,
        job_monitoring_interval=monitoring_interval_s,
        maintenance_interval=maintenance_interval_s,
        work_horse_killed_handler=_horse_killed,
    )
    worker.heartbeat_grace_s = heartbeat_grace_s
    logging.basicConfig(level=log_level.upper())
    promoter = _RetryPromoter(redis_url, queue_name, worker.name)
    promoter.start()
    try:
        return bool(worker.work(burst=burst, logging_level=log_level.upper()))
    finally:
        promoter.stop.set()

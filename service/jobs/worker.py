"""The RQ worker that ``gridplace worker`` runs.

RQ keeps a running job in the queue's started-job registry until ``heartbeat TTL`` after the
worker's last heartbeat; a worker that dies (SIGKILL, lost host) stops heart-beating and its
job is moved to the failed registry — running our failure callback — once that TTL passed.
RQ hard-codes a 60 s grace on top of the monitoring interval; :class:`GridplaceWorker` makes
it configurable, so a dead worker is noticed in ``monitoring interval + grace`` seconds.
"""

from __future__ import annotations

import logging
import os
from typing import Any

from redis import Redis
from redis.exceptions import RedisError
from rq import Queue, Worker
from rq.job import Job

from service.errors import UnavailableError
from service.jobs import rq_tasks

DEFAULT_MONITORING_INTERVAL_S = 10
DEFAULT_HEARTBEAT_GRACE_S = 30
DEFAULT_MAINTENANCE_INTERVAL_S = 60


class GridplaceWorker(Worker):
    """An RQ :class:`~rq.Worker` with a configurable heartbeat grace period."""

    heartbeat_grace_s: int = DEFAULT_HEARTBEAT_GRACE_S

    def get_heartbeat_ttl(self, job: Job) -> int:
        interval = float(self.job_monitoring_interval)
        if job.timeout and job.timeout > 0:
            interval = max(1.0, min(job.timeout - self.current_job_working_time, interval))
        return int(interval) + int(self.heartbeat_grace_s)


def _horse_killed(job: Job, pid: int, status: int, rusage: Any) -> None:
    """RQ marks a job whose work horse died (OOM killer, SIGKILL) failed without running its
    failure callback; fail the gridplace job here instead of waiting for a poll."""
    signal_note = f" by signal {os.WTERMSIG(status)}" if os.WIFSIGNALED(status) else ""
    rq_tasks.on_part_failure(
        job, job.connection, RuntimeError,
        RuntimeError(f"its training process {pid} was killed{signal_note} (out of memory?)"),
        None,
    )  # fmt: skip


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
    return bool(worker.work(burst=burst, logging_level=log_level.upper()))

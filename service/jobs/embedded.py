"""Training without Redis: a local process pool, one task per chunk.

A coordinator thread per running job (at most ``train_workers`` at once; later jobs stay
``queued``) drives the pipeline steps through a shared
:class:`~concurrent.futures.ProcessPoolExecutor` of ``train_workers`` processes started with
the forkserver method (safe from a threaded server process); each pool process dies with the
server, even on ``kill -9`` (see :mod:`service.jobs.pool_process`). A chunked route's chunk
encoders and its chunk classifier run as separate tasks in parallel; the assembly and
publication start only when all of them succeeded. Job state is written by the steps into
the registry, so every API process sees it.
"""

from __future__ import annotations

import logging
import multiprocessing as mp
import os
import socket
import threading
import time
from concurrent.futures import (
    FIRST_EXCEPTION,
    Future,
    ProcessPoolExecutor,
    ThreadPoolExecutor,
    wait,
)
from concurrent.futures.process import BrokenProcessPool
from pathlib import Path
from typing import Any, TypeVar

from service.encoding import ModelParams
from service.errors import UnavailableError
from service.jobs import pipeline
from service.jobs.pool_process import init_pool_process, pid_exists
from service.jobs.workspace import Workspace
from service.registry import JobInfo, Registry, RouteSource
from service.settings import Settings

log = logging.getLogger(__name__)
T = TypeVar("T")
BACKEND = "embedded"
RECORD_RETRY_S = (0.5, 5.0)  # first and longest wait between tries of recording a failure


class _JobTimeout(Exception):
    pass


class EmbeddedBackend:
    """The default backend: training processes owned by this (server) process."""

    def __init__(self, settings: Settings, registry: Registry) -> None:
        self._settings = settings
        self._registry = registry
        self._data_dir = registry.data_dir
        self._workers = int(settings.train_workers)
        self._owner = f"{socket.gethostname()}:{os.getpid()}"
        self._lock = threading.Lock()
        self._pool: ProcessPoolExecutor | None = None
        self._coordinators = ThreadPoolExecutor(self._workers, thread_name_prefix="gridplace-job")
        self._active: set[str] = set()  # jobs of this process with a coordinator to come or running
        self._jobs_lock = threading.Lock()  # a job is created and made active as one step
        self._closed = False
        self._reap_orphaned_jobs()

    # -- TrainingBackend ------------------------------------------------------------------
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
        if self._closed:
            raise UnavailableError("the training backend is shut down")
        for _ in range(2):  # a second time after failing a stuck job the first one returned
            with self._jobs_lock:
                job, created = self._registry.create_job(
                    map_name, route=route, params=params.model_dump(mode="json"),
                    extractor=extractor, backend=BACKEND, idempotency_key=idempotency_key,
                    owner=self._owner, source=source, force=force,
                )  # fmt: skip
                if created:
                    self._active.add(job.id)
            if created:
                self._coordinators.submit(self._run, job.id)
                return job
            if job.done or not self._reconcile(job.id):
                return job
        return self._registry.get_job(job.id)

    def get_job(self, job_id: str) -> JobInfo:
        job = self._registry.get_job(job_id)
        if not job.done and self._reconcile(job_id):
            job = self._registry.get_job(job_id)
        return job

    def queue_depth(self) -> int:
        return self._registry.count_jobs(["queued"], backend=BACKEND)

    def check_available(self) -> None:
        if self._closed:
            raise UnavailableError("the training backend is shut down")

    def close(self) -> None:
        """Stop accepting jobs, fail the unfinished ones of this process, stop the pool."""
        if self._closed:
            return
        with self._lock:  # no task is being submitted (a process being spawned) past this point
            self._closed = True
            pool, self._pool = self._pool, None
        self._coordinators.shutdown(wait=False, cancel_futures=True)
        failed = 0
        for job_id, owner in self._registry.job_owners(BACKEND):
            if owner == self._owner:
                failed += self._registry.fail_job(job_id, "the server shut down before the job finished")
        if failed:
            log.warning("shutting down: %d unfinished training job(s) marked failed", failed)
        if pool is not None:
            _terminate(pool)

    # -- coordination ---------------------------------------------------------------------
    def _run(self, job_id: str) -> None:
        try:
            self._coordinate(job_id)
        finally:
            with self._jobs_lock:
                self._active.discard(job_id)

    def _coordinate(self, job_id: str) -> None:
        deadline = time.monotonic() + self._settings.job_timeout_s
        try:
            params = ModelParams.parse(**self._registry.get_job_spec(job_id).params)
            if params.n_chunks == 1:
                self._call(deadline, pipeline.train_single, self._data_dir, job_id)
                return
            self._call(deadline, pipeline.prepare, self._data_dir, job_id)
            parts = [self._submit(pipeline.train_chunk, self._data_dir, job_id, c)
                     for c in range(params.n_chunks)]  # fmt: skip
            parts.append(self._submit(pipeline.train_classifier, self._data_dir, job_id))
            self._wait_all(parts, deadline)
            self._call(deadline, pipeline.assemble, self._data_dir, job_id)
        except BaseException as exc:  # noqa: BLE001 - every failure ends the job, visibly
            self._fail(job_id, exc)

    def _call(self, deadline: float, fn: Any, *args: Any) -> Any:
        future = self._submit(fn, *args)
        self._wait_all([future], deadline)
        return future.result()

    def _wait_all(self, futures: list[Future[Any]], deadline: float) -> None:
        done, pending = wait(futures, timeout=max(0.0, deadline - time.monotonic()),
                             return_when=FIRST_EXCEPTION)  # fmt: skip
        failed = [f for f in done if not f.cancelled() and f.exception() is not None]
        if failed or pending:
            for f in pending:
                f.cancel()  # queued parts never start; running ones find the job finished
            if failed:
                raise failed[0].exception()  # type: ignore[misc]
            raise _JobTimeout(
                f"training exceeded the job time limit of {self._settings.job_timeout_s} s"
            )

    def _fail(self, job_id: str, exc: BaseException) -> None:
        if isinstance(exc, BrokenProcessPool):
            message = "a training process died unexpectedly (out of memory or killed)"
            self._reset_pool()
        elif isinstance(exc, pipeline.JobFinished):
            return
        else:
            message = pipeline.describe(exc)
        if self._record_failure(job_id, message):
            log.warning("training job %s failed: %s", job_id, message)
        Workspace(self._data_dir, job_id).remove()

    def _record_failure(self, job_id: str, message: str) -> bool:
        """``fail_job``, tried again while the registry is unreachable (the job failed, maybe
        because the registry went away: it must not read ``running`` once the registry is
        back). Gives up only when the backend shuts down."""
        wait_s, logged = RECORD_RETRY_S[0], False
        while True:
            try:
                recorded = self._registry.fail_job(job_id, message)
            except UnavailableError as exc:
                if self._closed:
                    log.error("training job %s failed (%s); the registry is unreachable and "
                              "the server is shutting down: not recorded", job_id, message)  # fmt: skip
                    return False
                if not logged:
                    log.warning("training job %s failed (%s) but the registry is unreachable "
                                "(%s): recording it when the registry is back", job_id,
                                message, exc.message)  # fmt: skip
                    logged = True
                time.sleep(wait_s)
                wait_s = min(RECORD_RETRY_S[1], 2 * wait_s)
                continue
            if logged:
                log.warning("training job %s: its failure is recorded now that the registry "
                            "is back", job_id)  # fmt: skip
            return recorded

    def _submit(self, fn: Any, *args: Any) -> Future[Any]:
        """Submit a task to the pool, started on first use. Under the lock: a submit may spawn
        a process, and :meth:`close` must see every process it has to stop."""
        with self._lock:
            if self._closed:
                raise UnavailableError("the training backend is shut down")
            if self._pool is None:
                ctx = mp.get_context("forkserver")
                ctx.set_forkserver_preload(["service.jobs.pipeline"])
                threads = max(1, (os.cpu_count() or 1) // self._workers)
                self._pool = ProcessPoolExecutor(
                    self._workers, mp_context=ctx, initializer=init_pool_process,
                    initargs=(os.getpid(), threads),
                )  # fmt: skip
            return self._pool.submit(fn, *args)

    def _reset_pool(self) -> None:
        with self._lock:
            pool, self._pool = self._pool, None
        if pool is not None:
            _terminate(pool)

    # -- jobs whose process is gone ---------------------------------------------------------
    def _reconcile(self, job_id: str) -> bool:
        """Fail an unfinished job that can no longer finish: its process is gone, or it is
        this process's and no coordinator of it is left (one that ended without recording a
        result). True when the job was failed here."""
        owner = self._registry.get_job_spec(job_id).owner
        if owner != self._owner:
            return self._reap_if_orphaned(job_id, owner)
        with self._jobs_lock:
            if job_id in self._active or self._closed:
                return False
        failed = self._registry.fail_job(
            job_id, "the job's coordinator ended without recording its result"
        )
        if failed:
            log.warning("training job %s had no coordinator left: marked failed", job_id)
            Workspace(self._data_dir, job_id).remove()
        return failed

    def _reap_orphaned_jobs(self) -> None:
        for job_id, owner in self._registry.job_owners(BACKEND):
            self._reap_if_orphaned(job_id, owner)

    def _reap_if_orphaned(self, job_id: str, owner: str | None) -> bool:
        """Fail a job whose owning process on this host no longer exists (True if so)."""
        if owner is None or owner == self._owner:
            return False
        host, _, pid = owner.rpartition(":")
        if host != socket.gethostname() or not pid.isdigit() or pid_exists(int(pid)):
            return False
        if self._registry.fail_job(
            job_id, f"the server process {pid} that ran this job exited before it finished"
        ):
            Workspace(self._data_dir, job_id).remove()
            return True
        return False


def _terminate(pool: ProcessPoolExecutor) -> None:
    """Stop a pool now, killing tasks in progress (their jobs are already marked failed)."""
    processes = list((getattr(pool, "_processes", None) or {}).values())  # no public API
    # taken before shutdown(), which drops the pool's reference to it
    manager = getattr(pool, "_executor_manager_thread", None)  # no public API
    pool.shutdown(wait=False, cancel_futures=True)
    for proc in processes:
        proc.terminate()
    # Let the pool's manager thread see its processes gone and close its wake-up pipe now:
    # left running, it races at interpreter exit with concurrent.futures' own exit hook,
    # which writes to that pipe (CPython 3.11: "OSError: Bad file descriptor", printed as
    # an ignored exception on a graceful shutdown that lost the race).
    if manager is not None:
        manager.join(timeout=10.0)
        if manager.is_alive():
            log.warning("the training pool's manager thread did not stop within 10 s")

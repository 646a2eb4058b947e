"""Training-job bookkeeping in the registry database.

Every training backend (embedded process pool, RQ workers on other hosts) records job state
here, so any API process answers ``GET /v1/jobs/{id}`` from one place. State only moves
forward: ``queued → running → succeeded | failed``; a finished job is never changed again,
so a late progress report from a straggling worker cannot resurrect a failed job.
"""

from __future__ import annotations

import sqlite3
import uuid
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from service.errors import InvalidInputError, NotFoundError
from service.registry.db import Database, dumps, from_text, loads, to_text, ts, utcnow
from service.registry.models import JobInfo, JobSpec
from service.registry.names import check_map_name

MAX_IDEMPOTENCY_KEY = 200
_OPEN = "state IN ('queued', 'running')"


def _job_from_row(row: sqlite3.Row) -> JobInfo:
    return JobInfo(
        id=row["id"],
        map=row["map"],
        state=row["state"],
        stage=row["stage"],
        chunks_done=row["chunks_done"],
        chunks_total=row["chunks_total"],
        created_at=ts(row["created_at"]),
        started_at=from_text(row["started_at"]),
        finished_at=from_text(row["finished_at"]),
        error=row["error"],
        version=row["version"],
        idempotency_key=row["idempotency_key"],
        timings=loads(row["timings"]) or {},
    )


class JobTable:
    """Mixed into :class:`~service.registry.Registry`; needs ``self.db`` and ``self.data_dir``."""

    db: Database
    data_dir: Path

    def create_job(
        self,
        map_name: str,
        *,
        route: Path,
        params: dict[str, Any],
        extractor: dict[str, Any] | None,
        backend: str,
        idempotency_key: str | None = None,
        owner: str | None = None,
    ) -> tuple[JobInfo, bool]:
        """A new queued job, or the existing one for ``(map, idempotency_key)``.

        Returns ``(job, created)``; the uniqueness is enforced by the database, so two
        processes racing with the same key get the same job and only one trains.
        """
        check_map_name(map_name)
        if idempotency_key is not None and not 1 <= len(idempotency_key) <= MAX_IDEMPOTENCY_KEY:
            raise InvalidInputError(
                f"idempotency keys are 1-{MAX_IDEMPOTENCY_KEY} characters long"
            )
        job_id = uuid.uuid4().hex
        route = Path(route)
        try:
            stored_route = str(route.resolve().relative_to(self.data_dir.resolve()))
        except ValueError:
            stored_route = str(route.resolve())
        spec = JobSpec(
            job_id=job_id, map=map_name, route=stored_route, params=params,
            extractor=extractor, backend=backend, owner=owner,
        )  # fmt: skip
        with self.db.transaction() as conn:
            if idempotency_key is not None:
                row = conn.execute(
                    "SELECT * FROM jobs WHERE map = ? AND idempotency_key = ?",
                    (map_name, idempotency_key),
                ).fetchone()
                if row is not None:
                    return _job_from_row(row), False
            conn.execute(
                "INSERT INTO jobs (id, map, state, stage, created_at, idempotency_key, spec, "
                "backend, owner) VALUES (?, ?, 'queued', 'queued', ?, ?, ?, ?, ?)",
                (job_id, map_name, to_text(utcnow()), idempotency_key,
                 spec.model_dump_json(), backend, owner),
            )  # fmt: skip
        return self.get_job(job_id), True

    def get_job(self, job_id: str) -> JobInfo:
        with self.db.connect() as conn:
            row = conn.execute("SELECT * FROM jobs WHERE id = ?", (job_id,)).fetchone()
        if row is None:
            raise NotFoundError(f"no training job {job_id!r}", job_id=job_id)
        return _job_from_row(row)

    def get_job_spec(self, job_id: str) -> JobSpec:
        with self.db.connect() as conn:
            row = conn.execute("SELECT spec FROM jobs WHERE id = ?", (job_id,)).fetchone()
        if row is None:
            raise NotFoundError(f"no training job {job_id!r}", job_id=job_id)
        return JobSpec.model_validate_json(row["spec"])

    def route_path(self, spec: JobSpec) -> Path:
        """The absolute route file of a job (relative paths are under ``data_dir``)."""
        path = Path(spec.route)
        return path if path.is_absolute() else self.data_dir / path

    def list_jobs(
        self,
        map_name: str | None = None,
        states: Iterable[str] | None = None,
        backend: str | None = None,
        limit: int = 100,
    ) -> list[JobInfo]:
        """Newest first."""
        where, args = self._job_filter(map_name, states, backend)
        with self.db.connect() as conn:
            rows = conn.execute(
                f"SELECT * FROM jobs {where} ORDER BY created_at DESC LIMIT ?", (*args, limit)
            ).fetchall()
        return [_job_from_row(r) for r in rows]

    def count_jobs(self, states: Iterable[str], backend: str | None = None) -> int:
        where, args = self._job_filter(None, states, backend)
        with self.db.connect() as conn:
            return int(conn.execute(f"SELECT COUNT(*) FROM jobs {where}", args).fetchone()[0])

    def job_owners(self, backend: str) -> list[tuple[str, str | None]]:
        """``(job id, owner)`` of every unfinished job of ``backend``."""
        with self.db.connect() as conn:
            rows = conn.execute(
                f"SELECT id, owner FROM jobs WHERE backend = ? AND {_OPEN}", (backend,)
            ).fetchall()
        return [(r["id"], r["owner"]) for r in rows]

    @staticmethod
    def _job_filter(
        map_name: str | None, states: Iterable[str] | None, backend: str | None
    ) -> tuple[str, tuple[Any, ...]]:
        clauses: list[str] = []
        args: list[Any] = []
        if map_name is not None:
            clauses.append("map = ?")
            args.append(map_name)
        if states is not None:
            states = list(states)
            clauses.append(f"state IN ({', '.join('?' * len(states))})")
            args.extend(states)
        if backend is not None:
            clauses.append("backend = ?")
            args.append(backend)
        return ("WHERE " + " AND ".join(clauses)) if clauses else "", tuple(args)

    # -- state transitions (each one is a no-op on a finished job) ------------------------
    def mark_running(self, job_id: str, stage: str, chunks_total: int | None = None) -> bool:
        """Running at ``stage``; False if the job already finished (the caller must stop)."""
        with self.db.transaction() as conn:
            cur = conn.execute(
                f"UPDATE jobs SET state = 'running', stage = ?, "
                f"started_at = COALESCE(started_at, ?), "
                f"chunks_total = COALESCE(?, chunks_total) WHERE id = ? AND {_OPEN}",
                (stage, to_text(utcnow()), chunks_total, job_id),
            )
        return cur.rowcount == 1

    def record_progress(
        self,
        job_id: str,
        *,
        chunks_done_delta: int = 0,
        timings: dict[str, float] | None = None,
        stage: str | None = None,
    ) -> bool:
        """Add finished chunks and stage timings atomically; False if the job finished."""
        with self.db.transaction() as conn:
            merged = _open_job_timings(conn, job_id, timings)
            if merged is None:
                return False
            conn.execute(
                "UPDATE jobs SET chunks_done = chunks_done + ?, timings = ?, "
                "stage = COALESCE(?, stage) WHERE id = ?",
                (chunks_done_delta, dumps(merged), stage, job_id),
            )
        return True

    def finish_job(
        self, job_id: str, version: int, timings: dict[str, float] | None = None
    ) -> bool:
        """Succeeded with ``version``; False if the job had already finished."""
        with self.db.transaction() as conn:
            merged = _open_job_timings(conn, job_id, timings)
            if merged is None:
                return False
            conn.execute(
                "UPDATE jobs SET state = 'succeeded', stage = 'done', version = ?, "
                "chunks_done = chunks_total, timings = ?, finished_at = ?, "
                "started_at = COALESCE(started_at, ?) WHERE id = ?",
                (version, dumps(merged), to_text(utcnow()), to_text(utcnow()), job_id),
            )
        return True

    def discard_queued_job(self, job_id: str) -> bool:
        """Forget a job that was never queued anywhere (its queue was unreachable), so its
        idempotency key can be used again. Jobs that started are never deleted."""
        with self.db.transaction() as conn:
            cur = conn.execute(
                "DELETE FROM jobs WHERE id = ? AND state = 'queued' AND started_at IS NULL",
                (job_id,),
            )
        return cur.rowcount == 1

    def fail_job(self, job_id: str, error: str) -> bool:
        """Failed with ``error``; False if the job had already finished.

        A job whose version was already published (its process died before recording the
        success) is finished as succeeded instead: a published version's job never reads
        failed."""
        now = to_text(utcnow())
        with self.db.transaction() as conn:
            published = conn.execute(
                "SELECT version FROM versions WHERE job_id = ?", (job_id,)
            ).fetchone()
            if published is not None:
                conn.execute(
                    f"UPDATE jobs SET state = 'succeeded', stage = 'done', version = ?, "
                    f"chunks_done = chunks_total, finished_at = ? WHERE id = ? AND {_OPEN}",
                    (published[0], now, job_id),
                )
                return False
            cur = conn.execute(
                f"UPDATE jobs SET state = 'failed', error = ?, finished_at = ? "
                f"WHERE id = ? AND {_OPEN}",
                (error[:4000], now, job_id),
            )
        return cur.rowcount == 1


def _open_job_timings(
    conn: sqlite3.Connection, job_id: str, timings: dict[str, float] | None
) -> dict[str, float] | None:
    """The job's timings merged with ``timings``; ``None`` if the job is unknown or finished."""
    row = conn.execute(f"SELECT timings FROM jobs WHERE id = ? AND {_OPEN}", (job_id,)).fetchone()
    if row is None:
        return None
    return {**(loads(row["timings"]) or {}), **(timings or {})}

"""Training-job bookkeeping in the registry database.

Every training backend (embedded process pool, RQ workers on other hosts) records job state
here, so any API process answers ``GET /v1/jobs/{id}`` from one place. State only moves
forward: ``queued → running → succeeded | failed``; a finished job is never changed again,
so a late progress report from a straggling worker cannot resurrect a failed job.
"""

from __future__ import annotations

import hashlib
import uuid
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from sqlalchemy import Connection, RowMapping, bindparam, text

from service.errors import InvalidInputError, NotFoundError
from service.registry.db import Database, dumps, from_text, loads, to_text, ts, utcnow
from service.registry.job_cursor import decode_cursor
from service.registry.models import JobInfo, JobSpec, RouteSource
from service.registry.names import check_map_name
from service.wire import JobProgress, PartProgress

MAX_IDEMPOTENCY_KEY = 200
MAX_RETRIES_KEPT = 200
MAX_PAGE = 500
_OPEN = "state IN ('queued', 'running')"


def fingerprint(source: RouteSource, params: dict[str, Any], extractor: dict[str, Any] | None) -> str:
    """What makes two uploads the same training: the same descriptors, parameters and
    extractor (``params`` as the full validated set, so an explicit default equals none)."""
    payload = dumps({"content": source.content_sha256, "params": params, "extractor": extractor})
    return hashlib.sha256(payload.encode()).hexdigest()


def _no_job(job_id: str) -> NotFoundError:
    return NotFoundError(f"no training job {job_id!r}", job_id=job_id)


def _job_from_row(row: RowMapping) -> JobInfo:
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
        content_sha256=row["content_sha256"],
        retries=loads(row["retries"]) or [],
        progress=_progress(loads(row["progress"]), row["chunks_total"],
                           row["state"] == "succeeded"),
    )  # fmt: skip


def _progress(stored: dict[str, Any] | None, n_parts: int, succeeded: bool) -> JobProgress:
    """The job's fit progress from what its parts recorded: the mean of every part's
    done/total over the job's ``n_parts`` parts (those not started count 0); 1 on success."""
    stored = stored or {}
    parts = {k: PartProgress(**v) for k, v in (stored.get("parts") or {}).items()}
    shares = sum(min(1.0, p.done / p.total) if p.total > 0 else 1.0 for p in parts.values())
    fraction = 1.0 if succeeded else shares / max(n_parts, len(parts), 1)
    return JobProgress(fraction=fraction, detail=stored.get("detail", ""), parts=parts)


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
        source: RouteSource | None = None,
        force: bool = False,
    ) -> tuple[JobInfo, bool]:
        """A new queued job, or the existing one for ``(map, idempotency_key)``, or — unless
        ``force`` — the existing job that trains (or trained, and its version still exists)
        the same ``source`` with the same parameters and extractor.

        Returns ``(job, created)``; both look-ups and the insert run under the write lock, so
        two processes racing with the same upload get the same job and only one trains.
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
            extractor=extractor, backend=backend, owner=owner, source=source,
        )  # fmt: skip
        fp = None if source is None else fingerprint(source, params, extractor)
        with self.db.transaction() as conn:
            if idempotency_key is not None:
                row = conn.execute(
                    text("SELECT * FROM jobs WHERE map = :m AND idempotency_key = :k"),
                    {"m": map_name, "k": idempotency_key},
                ).mappings().first()
                if row is not None:
                    return _job_from_row(row), False
            if fp is not None and not force:
                same = _same_training(conn, map_name, fp)
                if same is not None:
                    return same.model_copy(update={"reused": True}), False
            conn.execute(
                text("INSERT INTO jobs (id, map, state, stage, created_at, idempotency_key, "
                     "spec, backend, owner, content_sha256, fingerprint) VALUES (:id, :m, "
                     "'queued', 'queued', :t, :k, :spec, :backend, :owner, :sha, :fp)"),
                {"id": job_id, "m": map_name, "t": to_text(utcnow()), "k": idempotency_key,
                 "spec": spec.model_dump_json(), "backend": backend, "owner": owner,
                 "sha": None if source is None else source.content_sha256, "fp": fp},
            )  # fmt: skip
        return self.get_job(job_id), True

    def get_job(self, job_id: str) -> JobInfo:
        if "\x00" in job_id:  # no job id holds one (PostgreSQL's text cannot)
            raise _no_job(job_id)
        with self.db.connect() as conn:
            row = conn.execute(
                text("SELECT * FROM jobs WHERE id = :j"), {"j": job_id}
            ).mappings().first()  # fmt: skip
        if row is None:
            raise _no_job(job_id)
        return _job_from_row(row)

    def get_job_spec(self, job_id: str) -> JobSpec:
        if "\x00" in job_id:
            raise _no_job(job_id)
        with self.db.connect() as conn:
            row = conn.execute(
                text("SELECT spec FROM jobs WHERE id = :j"), {"j": job_id}
            ).mappings().first()  # fmt: skip
        if row is None:
            raise _no_job(job_id)
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
        after: str | None = None,
    ) -> list[JobInfo]:
        """Newest first; ``after``: a cursor from :func:`~service.registry.job_cursor.encode_cursor` (the next page)."""
        where, args = self._job_filter(map_name, states, backend)
        if after is not None:
            created_at, job_id = decode_cursor(after)
            where.append("(created_at < :c_at OR (created_at = :c_at AND id < :c_id))")
            args.update(c_at=created_at, c_id=job_id)
        stmt = text(
            f"SELECT * FROM jobs {_where(where)} ORDER BY created_at DESC, id DESC LIMIT :limit"
        )
        with self.db.connect() as conn:
            rows = conn.execute(_expanding(stmt, args), {**args, "limit": limit}).mappings()
            return [_job_from_row(r) for r in rows]

    def count_jobs(self, states: Iterable[str], backend: str | None = None) -> int:
        where, args = self._job_filter(None, states, backend)
        stmt = text(f"SELECT COUNT(*) FROM jobs {_where(where)}")
        with self.db.connect() as conn:
            return int(conn.execute(_expanding(stmt, args), args).scalar_one())

    def job_owners(self, backend: str) -> list[tuple[str, str | None]]:
        """``(job id, owner)`` of every unfinished job of ``backend``."""
        with self.db.connect() as conn:
            rows = conn.execute(
                text(f"SELECT id, owner FROM jobs WHERE backend = :b AND {_OPEN}"), {"b": backend}
            ).mappings().all()  # fmt: skip
        return [(r["id"], r["owner"]) for r in rows]

    def parts_done(self, job_id: str) -> set[str]:
        """The parts of a job recorded as finished (see :meth:`record_progress`)."""
        with self.db.connect() as conn:
            value = conn.execute(
                text("SELECT parts_done FROM jobs WHERE id = :j"), {"j": job_id}
            ).scalar_one_or_none()  # fmt: skip
        return set(loads(value) or [])

    @staticmethod
    def _job_filter(
        map_name: str | None, states: Iterable[str] | None, backend: str | None
    ) -> tuple[list[str], dict[str, Any]]:
        clauses: list[str] = []
        args: dict[str, Any] = {}
        if map_name is not None:
            clauses.append("map = :map")
            args["map"] = map_name
        if states is not None:
            clauses.append("state IN :states")
            args["states"] = list(states)
        if backend is not None:
            clauses.append("backend = :backend")
            args["backend"] = backend
        return clauses, args

    # -- state transitions (each one is a no-op on a finished job) ------------------------
    def mark_running(self, job_id: str, stage: str, chunks_total: int | None = None) -> bool:
        """Running at ``stage``; False if the job already finished (the caller must stop)."""
        with self.db.transaction() as conn:
            cur = conn.execute(
                text(f"UPDATE jobs SET state = 'running', stage = :stage, "
                     f"started_at = COALESCE(started_at, :now), "
                     f"chunks_total = COALESCE(:total, chunks_total) WHERE id = :j AND {_OPEN}"),
                {"stage": stage, "now": to_text(utcnow()), "total": chunks_total, "j": job_id},
            )  # fmt: skip
        return cur.rowcount == 1

    def record_progress(
        self,
        job_id: str,
        *,
        chunks_done_delta: int = 0,
        timings: dict[str, float] | None = None,
        stage: str | None = None,
        part: str | None = None,
    ) -> bool:
        """Add finished chunks and stage timings atomically; False if the job finished.

        With ``part``, the progress counts once per part: a retried part that finishes again
        (its first run died after finishing) does not count its chunks twice."""
        with self.db.transaction() as conn:
            row = _open_job(conn, job_id)
            if row is None:
                return False
            merged = {**(loads(row["timings"]) or {}), **(timings or {})}
            parts = list(loads(row["parts_done"]) or [])
            if part is not None:
                if part in parts:
                    chunks_done_delta = 0
                else:
                    parts.append(part)
            conn.execute(
                text("UPDATE jobs SET chunks_done = chunks_done + :d, timings = :t, "
                     "stage = COALESCE(:s, stage), parts_done = :p WHERE id = :j"),
                {"d": chunks_done_delta, "t": dumps(merged), "s": stage, "p": dumps(parts),
                 "j": job_id},
            )  # fmt: skip
        return True

    def record_retry(self, job_id: str, part: str, attempt: int, error: str) -> bool:
        """Note that ``part`` failed on ``attempt`` and runs again; False if the job finished."""
        with self.db.transaction() as conn:
            row = _open_job(conn, job_id)
            if row is None:
                return False
            retries = list(loads(row["retries"]) or [])
            retries.append({"part": part, "attempt": int(attempt), "error": error[:1000],
                            "at": to_text(utcnow())})  # fmt: skip
            conn.execute(
                text("UPDATE jobs SET retries = :r WHERE id = :j"),
                {"r": dumps(retries[-MAX_RETRIES_KEPT:]), "j": job_id},
            )
        return True

    def record_fit_progress(
        self, job_id: str, part: str, done: int, total: int, detail: str = ""
    ) -> bool:
        """Record how far ``part`` of the job's fit got; False if the job finished."""
        with self.db.transaction() as conn:
            row = _open_job(conn, job_id)
            if row is None:
                return False
            progress = loads(row["progress"]) or {}
            progress.setdefault("parts", {})[part] = {
                "done": int(done), "total": int(total), "detail": detail,
            }  # fmt: skip
            progress["detail"] = detail
            conn.execute(
                text("UPDATE jobs SET progress = :p WHERE id = :j"),
                {"p": dumps(progress), "j": job_id},
            )
        return True

    def finish_job(
        self, job_id: str, version: int, timings: dict[str, float] | None = None
    ) -> bool:
        """Succeeded with ``version``; False if the job had already finished."""
        with self.db.transaction() as conn:
            row = _open_job(conn, job_id)
            if row is None:
                return False
            merged = {**(loads(row["timings"]) or {}), **(timings or {})}
            now = to_text(utcnow())
            conn.execute(
                text("UPDATE jobs SET state = 'succeeded', stage = 'done', version = :v, "
                     "chunks_done = chunks_total, timings = :t, finished_at = :now, "
                     "started_at = COALESCE(started_at, :now) WHERE id = :j"),
                {"v": version, "t": dumps(merged), "now": now, "j": job_id},
            )  # fmt: skip
        return True

    def discard_queued_job(self, job_id: str) -> bool:
        """Forget a job that was never queued anywhere (its queue was unreachable), so its
        idempotency key can be used again. Jobs that started are never deleted."""
        with self.db.transaction() as conn:
            cur = conn.execute(
                text("DELETE FROM jobs WHERE id = :j AND state = 'queued' "
                     "AND started_at IS NULL"),
                {"j": job_id},
            )  # fmt: skip
        return cur.rowcount == 1

    def fail_job(self, job_id: str, error: str) -> bool:
        """Failed with ``error``; False if the job had already finished.

        A job whose version was already published (its process died before recording the
        success) is finished as succeeded instead: a published version's job never reads
        failed."""
        now = to_text(utcnow())
        with self.db.transaction() as conn:
            published = conn.execute(
                text("SELECT version FROM versions WHERE job_id = :j"), {"j": job_id}
            ).first()
            if published is not None:
                conn.execute(
                    text(f"UPDATE jobs SET state = 'succeeded', stage = 'done', version = :v, "
                         f"chunks_done = chunks_total, finished_at = :now "
                         f"WHERE id = :j AND {_OPEN}"),
                    {"v": published[0], "now": now, "j": job_id},
                )  # fmt: skip
                return False
            cur = conn.execute(
                text(f"UPDATE jobs SET state = 'failed', error = :e, finished_at = :now "
                     f"WHERE id = :j AND {_OPEN}"),
                {"e": error[:4000], "now": now, "j": job_id},
            )  # fmt: skip
        return cur.rowcount == 1


def _open_job(conn: Connection, job_id: str) -> RowMapping | None:
    """The job's row if it exists and is not finished."""
    return conn.execute(
        text(f"SELECT * FROM jobs WHERE id = :j AND {_OPEN}"), {"j": job_id}
    ).mappings().first()  # fmt: skip


def _same_training(conn: Connection, map_name: str, fp: str) -> JobInfo | None:
    """The newest job of ``map_name`` with fingerprint ``fp`` that is still training, or
    that succeeded and whose version still exists; failed jobs never count."""
    rows = conn.execute(
        text("SELECT j.*, v.version AS live_version FROM jobs j "
             "LEFT JOIN versions v ON v.job_id = j.id "
             "WHERE j.map = :m AND j.fingerprint = :fp AND j.state != 'failed' "
             "ORDER BY j.created_at DESC, j.id DESC"),
        {"m": map_name, "fp": fp},
    ).mappings()  # fmt: skip
    for row in rows:
        if row["state"] != "succeeded" or row["live_version"] is not None:
            return _job_from_row(row)
    return None


def _where(clauses: list[str]) -> str:
    return ("WHERE " + " AND ".join(clauses)) if clauses else ""


def _expanding(stmt: Any, args: dict[str, Any]) -> Any:
    return stmt.bindparams(bindparam("states", expanding=True)) if "states" in args else stmt

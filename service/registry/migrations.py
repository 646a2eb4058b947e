"""Schema migrations of the registry database, with the schema version recorded in it.

``meta.schema_version`` is the version the database is at; ``schema_migrations`` records
when each step was applied. :func:`migrate` runs on every start (under the write lock, so
concurrent starts migrate once), applies the missing steps in order in one transaction, and
refuses a database whose schema is newer than this code knows: an old server must never
write into a schema it does not understand. The statements are portable between SQLite and
PostgreSQL (``BIGINT`` for every integer, ISO-8601 text for timestamps, JSON as text).
"""

from __future__ import annotations

from collections.abc import Sequence

from sqlalchemy import Connection, inspect, text

from service.errors import UnavailableError
from service.registry.db import Database, to_text, utcnow

_V1 = (
    """CREATE TABLE IF NOT EXISTS meta (
        key TEXT PRIMARY KEY,
        value BIGINT NOT NULL
    )""",
    "INSERT INTO meta (key, value) VALUES ('generation', 0) ON CONFLICT (key) DO NOTHING",
    """CREATE TABLE IF NOT EXISTS version_counters (
        map TEXT PRIMARY KEY,
        last_reserved BIGINT NOT NULL
    )""",
    """CREATE TABLE IF NOT EXISTS maps (
        name TEXT PRIMARY KEY,
        created_at TEXT NOT NULL,
        active_version BIGINT
    )""",
    """CREATE TABLE IF NOT EXISTS versions (
        map TEXT NOT NULL REFERENCES maps(name),
        version BIGINT NOT NULL,
        n_frames BIGINT NOT NULL,
        n_features BIGINT NOT NULL,
        kind TEXT NOT NULL,
        params TEXT NOT NULL,
        extractor TEXT,
        created_at TEXT NOT NULL,
        sha256 TEXT NOT NULL,
        footprint TEXT NOT NULL,
        artifact_bytes BIGINT NOT NULL,
        metrics TEXT NOT NULL,
        job_id TEXT UNIQUE,
        PRIMARY KEY (map, version)
    )""",
    """CREATE TABLE IF NOT EXISTS jobs (
        id TEXT PRIMARY KEY,
        map TEXT NOT NULL,
        state TEXT NOT NULL,
        stage TEXT NOT NULL,
        chunks_done BIGINT NOT NULL DEFAULT 0,
        chunks_total BIGINT NOT NULL DEFAULT 0,
        created_at TEXT NOT NULL,
        started_at TEXT,
        finished_at TEXT,
        error TEXT,
        version BIGINT,
        idempotency_key TEXT,
        timings TEXT NOT NULL DEFAULT '{}',
        spec TEXT NOT NULL,
        backend TEXT NOT NULL,
        owner TEXT,
        UNIQUE (map, idempotency_key)
    )""",
    "CREATE INDEX IF NOT EXISTS jobs_by_state ON jobs (state)",
)

_V2 = (
    # what was uploaded, so a repeat of the same route is recognised; free-form metadata
    "ALTER TABLE versions ADD COLUMN content_sha256 TEXT",
    "ALTER TABLE versions ADD COLUMN extra TEXT NOT NULL DEFAULT '{}'",
    "ALTER TABLE jobs ADD COLUMN content_sha256 TEXT",
    "ALTER TABLE jobs ADD COLUMN fingerprint TEXT",
    # parts finished (idempotent progress under retries) and the retries themselves
    "ALTER TABLE jobs ADD COLUMN parts_done TEXT NOT NULL DEFAULT '[]'",
    "ALTER TABLE jobs ADD COLUMN retries TEXT NOT NULL DEFAULT '[]'",
    "CREATE INDEX IF NOT EXISTS jobs_by_fingerprint ON jobs (map, fingerprint)",
    "CREATE INDEX IF NOT EXISTS jobs_by_created ON jobs (created_at, id)",
)

_V3 = (
    # how far each part of a job's fit got (see JobTable.record_fit_progress)
    "ALTER TABLE jobs ADD COLUMN progress TEXT NOT NULL DEFAULT '{}'",
)

_V4 = (
    # how many traversals of the route's places a version was trained on
    "ALTER TABLE versions ADD COLUMN n_traversals BIGINT NOT NULL DEFAULT 1",
)

MIGRATIONS: Sequence[tuple[int, str, Sequence[str]]] = (
    (1, "maps, versions, jobs and the generation counter", _V1),
    (2, "upload content hashes, version metadata, job parts and retries", _V2),
    (3, "fit progress of a job's parts", _V3),
    (4, "traversals a version was trained on", _V4),
)
SCHEMA_VERSION = MIGRATIONS[-1][0]


def _recorded_version(conn: Connection) -> int:
    """The schema version the database is at (0: empty database)."""
    if not inspect(conn).has_table("meta"):
        return 0
    row = conn.execute(text("SELECT value FROM meta WHERE key = 'schema_version'")).fetchone()
    if row is None:  # a database from before the version was recorded: v1's tables
        return 1 if inspect(conn).has_table("versions") else 0
    return int(row[0])


def schema_version(db: Database) -> int:
    with db.connect() as conn:
        return _recorded_version(conn)


def migrate(db: Database) -> int:
    """Bring the schema to :data:`SCHEMA_VERSION`; returns the version it was at."""
    with db.connect() as conn:  # the common case (up to date) takes no write lock
        current = _recorded_version(conn)
    _refuse_newer(db, current)
    if current == SCHEMA_VERSION:
        return current
    with db.transaction() as conn:
        current = _recorded_version(conn)  # again, under the lock: another process may have
        _refuse_newer(db, current)
        for version, description, statements in MIGRATIONS:
            if version <= current:
                continue
            for statement in statements:
                conn.execute(text(statement))
            _record(conn, version, description)
    return current


def _record(conn: Connection, version: int, description: str) -> None:
    conn.execute(text(
        "CREATE TABLE IF NOT EXISTS schema_migrations (version BIGINT PRIMARY KEY, "
        "description TEXT NOT NULL, applied_at TEXT NOT NULL)"
    ))  # fmt: skip
    conn.execute(
        text("INSERT INTO schema_migrations (version, description, applied_at) "
             "VALUES (:v, :d, :t) ON CONFLICT (version) DO NOTHING"),
        {"v": version, "d": description, "t": to_text(utcnow())},
    )  # fmt: skip
    conn.execute(
        text("INSERT INTO meta (key, value) VALUES ('schema_version', :v) "
             "ON CONFLICT (key) DO UPDATE SET value = :v"),
        {"v": version},
    )  # fmt: skip


def _refuse_newer(db: Database, current: int) -> None:
    if current > SCHEMA_VERSION:
        raise UnavailableError(
            f"the registry database ({db.where}) has schema version {current}, newer than "
            f"this gridplace knows ({SCHEMA_VERSION}); upgrade gridplace before using it",
            registry=db.where, schema_version=current, supported=SCHEMA_VERSION,
        )  # fmt: skip

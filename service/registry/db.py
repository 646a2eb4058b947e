"""The registry's SQLite database: schema, connections and write transactions.

One short-lived connection per operation keeps the registry safe to share between threads
and processes (API workers, training processes) on one data directory. WAL mode lets readers
proceed while one writer commits; every write runs in ``BEGIN IMMEDIATE`` so concurrent
writers queue on the busy timeout instead of failing half-way.
"""

from __future__ import annotations

import json
import sqlite3
from collections.abc import Iterator
from contextlib import contextmanager
from datetime import UTC, datetime
from pathlib import Path
from typing import Any, Literal

from service.errors import UnavailableError

SCHEMA_VERSION = 1
JournalMode = Literal["wal", "delete"]
BUSY_TIMEOUT_MS = 30_000

SCHEMA = """
CREATE TABLE IF NOT EXISTS meta (
    key TEXT PRIMARY KEY,
    value INTEGER NOT NULL
);
INSERT OR IGNORE INTO meta (key, value) VALUES ('generation', 0);
INSERT OR IGNORE INTO meta (key, value) VALUES ('schema_version', 1);
CREATE TABLE IF NOT EXISTS version_counters (
    map TEXT PRIMARY KEY,
    last_reserved INTEGER NOT NULL
);
CREATE TABLE IF NOT EXISTS maps (
    name TEXT PRIMARY KEY,
    created_at TEXT NOT NULL,
    active_version INTEGER
);
CREATE TABLE IF NOT EXISTS versions (
    map TEXT NOT NULL REFERENCES maps(name),
    version INTEGER NOT NULL,
    n_frames INTEGER NOT NULL,
    n_features INTEGER NOT NULL,
    kind TEXT NOT NULL,
    params TEXT NOT NULL,
    extractor TEXT,
    created_at TEXT NOT NULL,
    sha256 TEXT NOT NULL,
    footprint TEXT NOT NULL,
    artifact_bytes INTEGER NOT NULL,
    metrics TEXT NOT NULL,
    job_id TEXT UNIQUE,
    PRIMARY KEY (map, version)
);
CREATE TABLE IF NOT EXISTS jobs (
    id TEXT PRIMARY KEY,
    map TEXT NOT NULL,
    state TEXT NOT NULL,
    stage TEXT NOT NULL,
    chunks_done INTEGER NOT NULL DEFAULT 0,
    chunks_total INTEGER NOT NULL DEFAULT 0,
    created_at TEXT NOT NULL,
    started_at TEXT,
    finished_at TEXT,
    error TEXT,
    version INTEGER,
    idempotency_key TEXT,
    timings TEXT NOT NULL DEFAULT '{}',
    spec TEXT NOT NULL,
    backend TEXT NOT NULL,
    owner TEXT,
    UNIQUE (map, idempotency_key)
);
CREATE INDEX IF NOT EXISTS jobs_by_state ON jobs (state);
"""


def utcnow() -> datetime:
    return datetime.now(UTC)


def to_text(ts: datetime | None) -> str | None:
    return None if ts is None else ts.astimezone(UTC).isoformat()


def from_text(text: str | None) -> datetime | None:
    return None if text is None else datetime.fromisoformat(text)


def ts(text: str) -> datetime:
    """A timestamp column that is never NULL."""
    return datetime.fromisoformat(text)


def dumps(value: Any) -> str:
    return json.dumps(value, sort_keys=True, default=_json_default)


def loads(text: str | None) -> Any:
    return None if text is None else json.loads(text)


def _json_default(value: Any) -> Any:
    if hasattr(value, "item"):  # numpy scalars
        return value.item()
    if hasattr(value, "tolist"):  # numpy arrays
        return value.tolist()
    if isinstance(value, tuple | set | frozenset):
        return list(value)
    if isinstance(value, Path):
        return str(value)
    raise TypeError(f"{type(value).__name__} is not JSON serialisable")


class Database:
    """Connections to ``registry.sqlite3`` with the pragmas every connection needs."""

    def __init__(self, path: Path, journal_mode: JournalMode = "wal") -> None:
        self.path = path
        path.parent.mkdir(parents=True, exist_ok=True)
        with self.connect() as conn:
            mode = conn.execute(f"PRAGMA journal_mode={journal_mode.upper()}").fetchone()[0]
            if str(mode).lower() != journal_mode:
                raise UnavailableError(
                    f"the registry database {path} is in {mode} mode and cannot switch to "
                    f"{journal_mode} while other processes use it; use one journal mode everywhere"
                )
            with self.write(conn):
                for statement in SCHEMA.split(";"):
                    if statement.strip():
                        conn.execute(statement)

    @contextmanager
    def connect(self) -> Iterator[sqlite3.Connection]:
        try:
            conn = sqlite3.connect(
                self.path, timeout=BUSY_TIMEOUT_MS / 1000, isolation_level=None
            )
        except sqlite3.Error as exc:
            raise UnavailableError(f"cannot open the registry database {self.path}: {exc}") from exc
        try:
            conn.row_factory = sqlite3.Row
            conn.execute(f"PRAGMA busy_timeout={BUSY_TIMEOUT_MS}")
            conn.execute("PRAGMA foreign_keys=ON")
            conn.execute("PRAGMA synchronous=FULL")
            yield conn
        finally:
            conn.close()

    @staticmethod
    @contextmanager
    def write(conn: sqlite3.Connection) -> Iterator[sqlite3.Connection]:
        """One write transaction that takes the write lock up front (no upgrade deadlocks)."""
        conn.execute("BEGIN IMMEDIATE")
        try:
            yield conn
        except BaseException:
            conn.execute("ROLLBACK")
            raise
        conn.execute("COMMIT")

    @contextmanager
    def transaction(self) -> Iterator[sqlite3.Connection]:
        with self.connect() as conn, self.write(conn):
            yield conn

    @staticmethod
    def bump_generation(conn: sqlite3.Connection) -> int:
        row = conn.execute(
            "UPDATE meta SET value = value + 1 WHERE key = 'generation' RETURNING value"
        ).fetchone()
        return int(row[0])

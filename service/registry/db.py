"""The registry's database: SQLite (embedded default) or PostgreSQL, through one code path.

:class:`Database` wraps a SQLAlchemy engine. Every statement the registry runs is portable SQL
(named parameters, ``ON CONFLICT``, ``RETURNING``), so SQLite and PostgreSQL run the same
queries. Writes are serialised exactly as on SQLite: a write transaction takes the database's
write lock up front (``BEGIN IMMEDIATE`` on SQLite, a transaction-scoped advisory lock on
PostgreSQL), so every invariant checked inside one transaction (publish-once per job, a failed
job never publishes, one active version per map) holds under concurrent writers in any number
of processes and hosts.

SQLite: one short-lived connection per operation (safe between threads and processes on one
data directory), WAL by default. PostgreSQL: a connection pool per process, pre-pinged, so a
database that went away and came back is used again without a restart. An unreachable
database is an :class:`~service.errors.UnavailableError` (HTTP 503) naming it (never its
password).
"""

from __future__ import annotations

import json
import os
import sqlite3
import weakref
from collections.abc import Iterator
from contextlib import contextmanager
from datetime import UTC, datetime
from pathlib import Path
from typing import Any, Literal

from sqlalchemy import Connection, Engine, create_engine, event, make_url, text
from sqlalchemy.engine import URL
from sqlalchemy.exc import ArgumentError, DBAPIError, InterfaceError, OperationalError
from sqlalchemy.exc import TimeoutError as PoolTimeoutError
from sqlalchemy.pool import NullPool

from service.errors import InvalidParameterError, UnavailableError

JournalMode = Literal["wal", "delete"]
BUSY_TIMEOUT_MS = 30_000
WRITE_LOCK_KEY = 0x67726964  # PostgreSQL advisory lock id of the registry's write lock
_WRITE = "gridplace_write"


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


def sqlite_url(path: Path) -> str:
    return f"sqlite:///{Path(path).resolve()}"


def parse_url(url: str) -> URL:
    """``url`` as a SQLAlchemy URL on a supported driver (``postgresql://`` uses psycopg 3)."""
    try:
        parsed = make_url(url)
    except ArgumentError as exc:
        raise InvalidParameterError(f"invalid registry URL: {exc}") from exc
    backend = parsed.get_backend_name()
    if backend == "postgresql":
        return parsed.set(drivername="postgresql+psycopg")
    if backend == "sqlite":
        return parsed.set(drivername="sqlite")
    raise InvalidParameterError(
        f"unsupported registry database {backend!r}: use postgresql://… or sqlite:///path"
    )


def describe_url(url: URL) -> str:
    """The URL for messages and logs: no password, ever."""
    return url.render_as_string(hide_password=True).replace("+psycopg", "")


class Database:
    """One engine per registry handle, with the per-dialect settings every connection needs."""

    def __init__(
        self,
        url: str,
        *,
        journal_mode: JournalMode = "wal",
        pool_size: int = 5,
        connect_timeout_s: float = 5.0,
    ) -> None:
        self.url = parse_url(url)
        self.where = describe_url(self.url)
        self.dialect = self.url.get_backend_name()
        self.engine = self._create_engine(pool_size, connect_timeout_s)
        _dispose_after_fork(self.engine)
        if self.is_sqlite:
            self._set_journal_mode(journal_mode)

    @property
    def is_sqlite(self) -> bool:
        return self.dialect == "sqlite"

    def _create_engine(self, pool_size: int, connect_timeout_s: float) -> Engine:
        if self.is_sqlite:
            database = self.url.database
            if not database or database == ":memory:":
                raise InvalidParameterError("the SQLite registry needs a file path")
            Path(database).parent.mkdir(parents=True, exist_ok=True)
            engine = create_engine(
                self.url, poolclass=NullPool,
                connect_args={"timeout": BUSY_TIMEOUT_MS / 1000, "check_same_thread": False},
            )  # fmt: skip

            @event.listens_for(engine, "connect")
            def _on_connect(dbapi_conn: sqlite3.Connection, _record: Any) -> None:
                dbapi_conn.isolation_level = None  # transactions are begun below, explicitly
                dbapi_conn.execute(f"PRAGMA busy_timeout={BUSY_TIMEOUT_MS}")
                dbapi_conn.execute("PRAGMA foreign_keys=ON")
                dbapi_conn.execute("PRAGMA synchronous=FULL")

            @event.listens_for(engine, "begin")
            def _on_begin(conn: Connection) -> None:
                # take the write lock up front: no lock-upgrade deadlocks between writers
                write = conn.get_execution_options().get(_WRITE, False)
                conn.exec_driver_sql("BEGIN IMMEDIATE" if write else "BEGIN")

            return engine
        return create_engine(
            self.url, pool_size=pool_size, max_overflow=pool_size, pool_pre_ping=True,
            pool_recycle=1800, pool_timeout=max(connect_timeout_s, 5.0),
            connect_args={"connect_timeout": max(1, int(round(connect_timeout_s))),
                          "application_name": "gridplace"},
        )  # fmt: skip

    def _set_journal_mode(self, journal_mode: JournalMode) -> None:
        with self._errors():
            with self.engine.connect() as conn:
                conn.commit()  # leave the autobegun transaction: the pragma needs none
                raw = conn.connection.dbapi_connection
                assert raw is not None
                mode = raw.execute(f"PRAGMA journal_mode={journal_mode.upper()}").fetchone()[0]
        if str(mode).lower() != journal_mode:
            raise UnavailableError(
                f"the registry database {self.where} is in {mode} mode and cannot switch to "
                f"{journal_mode} while other processes use it; use one journal mode everywhere"
            )

    # -- connections ----------------------------------------------------------------------
    @contextmanager
    def connect(self) -> Iterator[Connection]:
        """A connection for reads (each statement sees committed data)."""
        with self._errors(), self.engine.connect() as conn:
            yield conn

    @contextmanager
    def transaction(self) -> Iterator[Connection]:
        """One write transaction holding the registry's write lock until it commits."""
        with self._errors():
            with self.engine.connect().execution_options(**{_WRITE: True}) as conn:
                with conn.begin():
                    if not self.is_sqlite:
                        conn.execute(text("SELECT pg_advisory_xact_lock(:k)"),
                                     {"k": WRITE_LOCK_KEY})  # fmt: skip
                    yield conn

    @contextmanager
    def _errors(self) -> Iterator[None]:
        try:
            yield
        except (OperationalError, InterfaceError, PoolTimeoutError) as exc:
            raise UnavailableError(
                f"the registry database ({self.where}) is unreachable: {_first_line(exc)}",
                registry=self.where,
            ) from exc
        except DBAPIError as exc:
            if exc.connection_invalidated:
                raise UnavailableError(
                    f"the registry database ({self.where}) dropped the connection: "
                    f"{_first_line(exc)}", registry=self.where,
                ) from exc  # fmt: skip
            raise

    @staticmethod
    def bump_generation(conn: Connection) -> int:
        row = conn.execute(
            text("UPDATE meta SET value = value + 1 WHERE key = 'generation' RETURNING value")
        ).fetchone()
        assert row is not None
        return int(row[0])

    def close(self) -> None:
        self.engine.dispose()


def _first_line(exc: BaseException) -> str:
    orig = getattr(exc, "orig", None) or exc
    lines = str(orig).strip().splitlines()
    return lines[0] if lines else type(orig).__name__


def _dispose_after_fork(engine: Engine) -> None:
    """A forked child (an RQ work horse, a pool process) must not reuse the parent's pooled
    connections: it gets a fresh pool, the parent's sockets stay the parent's."""
    ref = weakref.ref(engine)

    def _child() -> None:
        eng = ref()
        if eng is not None:
            eng.dispose(close=False)

    os.register_at_fork(after_in_child=_child)

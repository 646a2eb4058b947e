"""Schema migrations, the recorded schema version, and the unreachable database (503).
Models are trained on SYNTHETIC routes (see conftest)."""

from __future__ import annotations

import multiprocessing as mp
import sqlite3
import time
from pathlib import Path

import pytest
from sqlalchemy import create_engine, text
from sqlalchemy.pool import NullPool

from service.errors import UnavailableError
from service.registry import Registry
from service.registry.db import parse_url
from service.registry.migrations import SCHEMA_VERSION, schema_version
from service.registry.scratch import ScratchDatabase

# the schema a data directory written by the first release holds (copied from that release)
_V1_SQLITE = """
CREATE TABLE meta (key TEXT PRIMARY KEY, value INTEGER NOT NULL);
INSERT INTO meta VALUES ('generation', 3), ('schema_version', 1);
CREATE TABLE version_counters (map TEXT PRIMARY KEY, last_reserved INTEGER NOT NULL);
CREATE TABLE maps (name TEXT PRIMARY KEY, created_at TEXT NOT NULL, active_version INTEGER);
CREATE TABLE versions (
    map TEXT NOT NULL REFERENCES maps(name), version INTEGER NOT NULL,
    n_frames INTEGER NOT NULL, n_features INTEGER NOT NULL, kind TEXT NOT NULL,
    params TEXT NOT NULL, extractor TEXT, created_at TEXT NOT NULL, sha256 TEXT NOT NULL,
    footprint TEXT NOT NULL, artifact_bytes INTEGER NOT NULL, metrics TEXT NOT NULL,
    job_id TEXT UNIQUE, PRIMARY KEY (map, version));
CREATE TABLE jobs (
    id TEXT PRIMARY KEY, map TEXT NOT NULL, state TEXT NOT NULL, stage TEXT NOT NULL,
    chunks_done INTEGER NOT NULL DEFAULT 0, chunks_total INTEGER NOT NULL DEFAULT 0,
    created_at TEXT NOT NULL, started_at TEXT, finished_at TEXT, error TEXT, version INTEGER,
    idempotency_key TEXT, timings TEXT NOT NULL DEFAULT '{}', spec TEXT NOT NULL,
    backend TEXT NOT NULL, owner TEXT, UNIQUE (map, idempotency_key));
CREATE INDEX jobs_by_state ON jobs (state);
"""


def test_a_first_release_sqlite_data_dir_is_migrated_and_keeps_working(tmp_path, model):
    from service.encoding import save_model

    data = tmp_path / "old"
    (data / "artifacts" / "m").mkdir(parents=True)
    manifest = save_model(model, data / "artifacts" / "m" / "v1")
    with sqlite3.connect(data / "registry.sqlite3") as conn:
        conn.executescript(_V1_SQLITE)
        conn.execute("INSERT INTO maps VALUES ('m', '2025-01-01T00:00:00+00:00', 1)")
        conn.execute("INSERT INTO version_counters VALUES ('m', 1)")
        conn.execute(
            "INSERT INTO versions VALUES ('m', 1, ?, ?, ?, '{}', NULL, "
            "'2025-01-01T00:00:00+00:00', ?, '{}', ?, '{}', 'job-1')",
            (manifest["n_frames"], manifest["n_features"], manifest["kind"],
             manifest["files"]["tensors.safetensors"]["sha256"], manifest["artifact_bytes"]),
        )  # fmt: skip
        conn.execute(
            "INSERT INTO jobs (id, map, state, stage, created_at, spec, backend, version) "
            "VALUES ('job-1', 'm', 'succeeded', 'done', '2025-01-01T00:00:00+00:00', ?, "
            "'embedded', 1)", ('{"job_id": "job-1", "map": "m", "route": "uploads/x.npy", '
                               '"params": {}, "extractor": null, "backend": "embedded"}',),
        )  # fmt: skip
    reg = Registry(data, url=None)
    assert schema_version(reg.db) == SCHEMA_VERSION
    v1 = reg.get_version("m", 1)
    assert v1.active and v1.content_sha256 is None and v1.extra == {}
    assert reg.generation() == 3
    assert reg.get_job("job-1").retries == [] and reg.get_job("job-1").version == 1
    assert reg.load_model("m", 1) is not None
    v2 = reg.publish("m", model, params={}, extractor=None, metrics={}, content_sha256="ab" * 32)
    assert (v2.version, v2.content_sha256) == (2, "ab" * 32)
    with sqlite3.connect(data / "registry.sqlite3") as conn:
        steps = conn.execute("SELECT version FROM schema_migrations ORDER BY version").fetchall()
    assert [s[0] for s in steps] == list(range(2, SCHEMA_VERSION + 1))
    reg.close()


def _set_schema_version(reg: Registry, version: int) -> None:
    with reg.db.transaction() as conn:
        conn.execute(text("UPDATE meta SET value = :v WHERE key = 'schema_version'"),
                     {"v": version})  # fmt: skip


@pytest.mark.parametrize("store", ["sqlite", "postgresql"])
def test_a_newer_schema_is_refused(tmp_path, store):
    scratch = ScratchDatabase() if store == "postgresql" else None
    url = scratch.create() if scratch is not None else None
    try:
        reg = Registry(tmp_path / "data", url=url)
        _set_schema_version(reg, SCHEMA_VERSION + 1)  # as a newer release would leave it
        reg.close()
        with pytest.raises(UnavailableError, match="newer than this gridplace knows") as info:
            Registry(tmp_path / "data", url=url)
        assert info.value.details["schema_version"] == SCHEMA_VERSION + 1
    finally:
        if scratch is not None:
            scratch.drop()


def _open(data_dir: str, url: str, out: mp.Queue) -> None:
    reg = Registry(Path(data_dir), url=url)
    out.put(schema_version(reg.db))
    reg.close()


def test_concurrent_first_starts_migrate_an_empty_postgres_database_once(tmp_path):
    with ScratchDatabase() as url:
        ctx = mp.get_context("fork")
        out: mp.Queue = ctx.Queue()
        procs = [ctx.Process(target=_open, args=(str(tmp_path), url, out)) for _ in range(4)]
        for p in procs:
            p.start()
        got = [out.get(timeout=60) for _ in procs]
        for p in procs:
            p.join(timeout=30)
            assert p.exitcode == 0
        assert got == [SCHEMA_VERSION] * 4
        engine = create_engine(parse_url(url), poolclass=NullPool)
        with engine.connect() as conn:
            steps = conn.execute(text("SELECT version FROM schema_migrations")).scalars().all()
        engine.dispose()
        assert sorted(steps) == list(range(1, SCHEMA_VERSION + 1))


def test_an_unreachable_postgres_is_a_503_naming_it_without_the_password(tmp_path):
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]  # nothing listens there once closed
    start = time.monotonic()
    with pytest.raises(UnavailableError) as info:
        Registry(tmp_path, url=f"postgresql://gp:s3cret@127.0.0.1:{port}/reg")
    assert time.monotonic() - start < 10
    assert f"127.0.0.1:{port}/reg" in info.value.message
    assert "s3cret" not in info.value.message and "s3cret" not in str(info.value.details)
    assert info.value.http_status == 503


def test_an_unsupported_registry_url_is_refused(tmp_path):
    from service.errors import InvalidParameterError

    with pytest.raises(InvalidParameterError, match="unsupported registry database"):
        Registry(tmp_path, url="mysql://root@localhost/x")

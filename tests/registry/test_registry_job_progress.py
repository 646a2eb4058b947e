"""Fit progress in the job table: per-part records, the job's fraction, and databases made
before the progress column existed."""

from __future__ import annotations

import sqlite3
from pathlib import Path

import pytest

from service.registry import Registry


def _job(registry: Registry) -> str:
    job, _ = registry.create_job(
        "route-p", route=registry.data_dir / "uploads" / "x.npy", params={"trainer": "ridge"},
        extractor=None, backend="embedded",
    )  # fmt: skip
    return job.id


def test_parts_report_separately_and_average_into_the_fraction(registry: Registry) -> None:
    job_id = _job(registry)
    assert registry.get_job(job_id).progress.fraction == 0.0
    registry.mark_running(job_id, "chunks", chunks_total=4)  # 3 chunks + the classifier
    assert registry.record_fit_progress(job_id, "chunk_0", 10, 40, "chunk_0: digit 1/2")
    assert registry.record_fit_progress(job_id, "chunk_classifier", 3, 3, "chunk_classifier")
    progress = registry.get_job(job_id).progress
    assert progress.fraction == pytest.approx((0.25 + 1.0) / 4)
    assert progress.detail == "chunk_classifier"  # the step last reported
    assert progress.parts["chunk_0"].done == 10 and progress.parts["chunk_0"].total == 40
    assert progress.parts["chunk_0"].detail == "chunk_0: digit 1/2"
    assert registry.record_fit_progress(job_id, "chunk_0", 40, 40, "chunk_0: done")
    assert registry.get_job(job_id).progress.fraction == pytest.approx(2 / 4)


def test_a_finished_job_takes_no_progress_and_reads_complete(registry: Registry) -> None:
    job_id = _job(registry)
    registry.mark_running(job_id, "fit", 1)
    assert registry.record_fit_progress(job_id, "fit", 5, 50, "digit 1/2: 5/25 classes")
    assert registry.fail_job(job_id, "timed out")
    assert not registry.record_fit_progress(job_id, "fit", 6, 50, "late")  # the fit stops
    failed = registry.get_job(job_id).progress
    assert failed.fraction == pytest.approx(0.1) and failed.detail.startswith("digit 1/2")

    done_id = _job(registry)
    registry.mark_running(done_id, "fit", 1)
    registry.finish_job(done_id, 1)
    assert registry.get_job(done_id).progress.fraction == 1.0


def test_a_database_without_the_progress_column_gets_it(tmp_path: Path) -> None:
    data = tmp_path / "old"
    data.mkdir()
    conn = sqlite3.connect(data / "registry.sqlite3")
    conn.executescript(
        """CREATE TABLE jobs (id TEXT PRIMARY KEY, map TEXT NOT NULL, state TEXT NOT NULL,
        stage TEXT NOT NULL, chunks_done INTEGER NOT NULL DEFAULT 0,
        chunks_total INTEGER NOT NULL DEFAULT 0, created_at TEXT NOT NULL, started_at TEXT,
        finished_at TEXT, error TEXT, version INTEGER, idempotency_key TEXT,
        timings TEXT NOT NULL DEFAULT '{}', spec TEXT NOT NULL, backend TEXT NOT NULL,
        owner TEXT, UNIQUE (map, idempotency_key));
        INSERT INTO jobs (id, map, state, stage, created_at, spec, backend)
        VALUES ('old-job', 'm', 'running', 'fit', '2026-01-01T00:00:00+00:00', '{}', 'embedded');"""
    )
    conn.commit()
    conn.close()
    registry = Registry(data)
    job = registry.get_job("old-job")
    assert job.progress.fraction == 0.0 and job.progress.parts == {}
    assert registry.record_fit_progress("old-job", "fit", 1, 2, "half")
    assert registry.get_job("old-job").progress.fraction == 0.5

"""A training job's progress field follows the fit in the embedded process pool, per class
while it runs and per part once it is done. Routes are SYNTHETIC (smooth random process)."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest

from service.encoding import ModelParams
from service.encoding.synthetic import smooth_route
from service.jobs.pipeline import PROGRESS_INTERVAL_S, FitReporter, JobFinished


def test_a_running_job_reports_per_class_progress(backend, route_file: Path, wait_done):
    # one digit of 800 classes with logreg: 800 one-vs-rest problems, several progress
    # intervals (PROGRESS_INTERVAL_S) even on an idle machine
    route = route_file.with_name("progress-route.npy")
    np.save(route, smooth_route(800, 64, seed=9).reference, allow_pickle=False)
    params = ModelParams.parse(trainer="logreg", n_patterns=1)
    job = backend.submit("progress", route, params, None, None)
    seen: list[tuple[float, str]] = []
    deadline = time.monotonic() + 120
    while not (current := backend.get_job(job.id)).done and time.monotonic() < deadline:
        if current.state == "running":
            seen.append((current.progress.fraction, current.progress.detail))
        time.sleep(0.05)
    done = wait_done(backend, job.id)
    assert done.state == "succeeded", done.error
    midway = [(f, d) for f, d in seen if 0.0 < f < 1.0]
    assert midway, f"no progress seen while the job ran: {seen[-5:]}"
    assert all(d.startswith("digit 1/1: ") and d.endswith("/800 classes") for _, d in midway)
    fractions = [f for f, _ in seen]
    assert fractions == sorted(fractions)
    assert done.progress.fraction == 1.0
    fit = done.progress.parts["fit"]
    assert fit.done == fit.total == 800 and fit.detail == "digit 1/1: 800/800 classes"


def test_a_chunked_job_records_every_part(backend, route_file, wait_done):
    params = ModelParams.parse(trainer="ridge", n_chunks=3)
    done = wait_done(backend, backend.submit("progress-chunked", route_file, params, None, None).id)
    assert done.state == "succeeded", done.error
    parts = done.progress.parts
    assert set(parts) == {"chunk_0", "chunk_1", "chunk_2", "chunk_classifier"}
    assert all(p.done == p.total > 0 for p in parts.values())
    assert parts["chunk_classifier"].total == 3  # one unit per chunk
    assert parts["chunk_1"].detail.startswith("chunk_1: digit ")
    assert done.progress.fraction == 1.0


class _Table:
    """Stands in for the registry's job table: records writes; ``open`` False = job ended."""

    def __init__(self) -> None:
        self.writes: list[tuple[str, int, int, str]] = []
        self.open = True

    def record_fit_progress(self, job_id: str, part: str, done: int, total: int,
                            detail: str) -> bool:  # fmt: skip
        self.writes.append((part, done, total, detail))
        return self.open


def test_reporter_throttles_classes_but_keeps_step_boundaries_and_the_end() -> None:
    table = _Table()
    report = FitReporter(table, "j", "fit")  # type: ignore[arg-type]
    report("digit 1/2", 0, 120)
    for c in range(1, 61):
        report(f"digit 1/2: {c}/60 classes", c, 120)  # within 0.5 s of the last write
    report("digit 2/2", 60, 120)  # a new digit is always written
    report("digit 2/2: 60/60 classes", 120, 120)  # so is the end
    assert [w[3] for w in table.writes] == ["digit 1/2", "digit 2/2", "digit 2/2: 60/60 classes"]
    time.sleep(PROGRESS_INTERVAL_S)
    report("digit 2/2: 1/60 classes", 61, 120)  # the interval passed: written
    assert table.writes[-1][3] == "digit 2/2: 1/60 classes"
    chunk = FitReporter(table, "j", "chunk_2")  # type: ignore[arg-type]
    chunk("digit 1/2", 0, 10)
    assert table.writes[-1] == ("chunk_2", 0, 10, "chunk_2: digit 1/2")  # parts say which


def test_reporter_stops_the_fit_when_the_job_ended() -> None:
    table = _Table()
    table.open = False
    with pytest.raises(JobFinished):
        FitReporter(table, "j", "fit")("digit 1/2", 0, 10)  # type: ignore[arg-type]

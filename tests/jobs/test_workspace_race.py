"""A part's result that lands while its job is failed elsewhere leaves no workspace behind."""

from __future__ import annotations

import pytest

from service.jobs import pipeline
from service.jobs.workspace import JobFinished, Workspace


def test_a_write_racing_with_the_jobs_failure_removes_the_workspace_it_brought_back(
    data_dir, registry, route_file
) -> None:
    job, _ = registry.create_job("race", route=route_file, params={}, extractor=None,
                                 backend="rq")  # fmt: skip
    workspace = Workspace(data_dir, job.id)

    def write_as_the_job_fails() -> None:
        # the writer checked the job before this point; meanwhile another process fails the
        # job and removes the workspace, and the write lands afterwards (recreating it)
        assert registry.fail_job(job.id, "chunk-1 failed: simulated")
        workspace.remove()
        (workspace.path / "chunk-00000").mkdir(parents=True)

    with pytest.raises(JobFinished):
        pipeline._write_while_open(registry, job.id, workspace, "chunk 0", write_as_the_job_fails)
    assert not workspace.path.exists()


def test_a_write_to_an_open_job_is_kept(data_dir, registry, route_file) -> None:
    job, _ = registry.create_job("open", route=route_file, params={}, extractor=None,
                                 backend="rq")  # fmt: skip
    workspace = Workspace(data_dir, job.id)
    pipeline._write_while_open(registry, job.id, workspace, "chunk 0",
                               lambda: workspace.path.mkdir(parents=True))  # fmt: skip
    assert workspace.path.is_dir()
    workspace.remove()

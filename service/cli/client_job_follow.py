"""Following a training job from the command line: a progress bar while it runs, then
whether the version it published is the one its map serves (and how to make it so)."""

from __future__ import annotations

from rich.progress import (
    BarColumn,
    Progress,
    SpinnerColumn,
    TaskProgressColumn,
    TextColumn,
    TimeElapsedColumn,
)

from service.cli.client_options import console, print_json
from service.client import GridplaceClient, Job, JobFailedError


def job_line(job: Job) -> str:
    chunks = f", {job.chunks_done}/{job.chunks_total} parts" if job.chunks_total > 1 else ""
    detail = f" {job.progress.detail}" if job.progress.detail and not job.done else ""
    return f"{job.map}: {job.state} ({job.stage}{chunks}){detail}"


def follow_job(gp: GridplaceClient, job: Job, timeout: float) -> Job:
    columns = (SpinnerColumn(), TextColumn("{task.description}"), BarColumn(),
               TaskProgressColumn(), TimeElapsedColumn())  # fmt: skip
    with Progress(*columns, console=console, transient=True) as bar:
        task = bar.add_task(job_line(job), total=1.0, completed=job.progress.fraction)

        def update(j: Job) -> None:
            bar.update(task, description=job_line(j), completed=j.progress.fraction)

        return gp.wait_for_job(job.id, timeout=timeout, on_update=update)


def version_status(gp: GridplaceClient, job: Job) -> str:
    """Whether the job's version is the one its map serves, and how to make it so."""
    active = gp.get_map(job.map).active_version
    if active == job.version:
        return f"version {job.version} is active (served for map {job.map})"
    now = f"map {job.map} serves version {active}" if active is not None else f"map {job.map} serves no version"
    return (f"version {job.version} is NOT active ({now}); activate it with: "
            f"gridplace client activate {job.map} {job.version}")  # fmt: skip


def report_job(gp: GridplaceClient, job: Job, as_json: bool) -> None:
    if as_json:
        print_json(job)
    elif job.version is not None:
        console.print(f"job {job.id}: {job.map} {job.state} → {version_status(gp, job)}",
                      highlight=False, soft_wrap=True)  # fmt: skip
    else:
        console.print(f"job {job.id}: {job.map} {job.state} ({job.stage})", highlight=False)
    if job.state == "failed":
        raise JobFailedError(f"job {job.id} failed: {job.error}", job_id=job.id)

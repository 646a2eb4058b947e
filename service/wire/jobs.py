"""Training jobs as the admin API (and the registry) describe them."""

from __future__ import annotations

from datetime import datetime

from pydantic import Field, computed_field

from service.wire.base import TERMINAL_STATES, Answer, JobState


class JobRetry(Answer):
    """One part of a job that failed and was queued again."""

    part: str = Field(description="e.g. chunk-3, classifier, prepare, train")
    attempt: int = Field(description="the attempt that failed (1 = the first run)")
    error: str
    at: datetime


class PartProgress(Answer):
    """How far one part of a job (``fit``, ``chunk_3``, ``chunk_classifier``) got."""

    done: int = Field(description="units of work finished (one unit: one class of a digit)")
    total: int = Field(description="units of work of this part")
    detail: str = Field("", description="the step last reported")


class JobProgress(Answer):
    """Progress of a job's fit, as its training processes report it."""

    fraction: float = Field(
        0.0, ge=0.0, le=1.0,
        description="share of the fit done: each part's done/total, averaged over all parts "
        "of the job (fit, or chunk_<c> and chunk_classifier; parts not started count 0); "
        "1 once the job succeeded",
    )
    detail: str = Field("", description="the step last reported, e.g. 'digit 2/2: 17/60 classes'")
    parts: dict[str, PartProgress] = Field(default_factory=dict)


class Job(Answer):
    """A training job's externally visible state."""

    id: str
    map: str
    state: JobState
    stage: str = Field(description="what the job is doing now, e.g. 'training chunk 2/4'")
    chunks_done: int
    chunks_total: int
    created_at: datetime
    started_at: datetime | None
    finished_at: datetime | None
    error: str | None = Field(description="why it failed")
    version: int | None = Field(description="the version it published")
    idempotency_key: str | None
    timings: dict[str, float] = Field(default_factory=dict, description="stage → seconds")
    content_sha256: str | None = Field(None, description="sha256 of the uploaded descriptors")
    retries: list[JobRetry] = Field(
        default_factory=list, description="parts that failed and were run again, oldest first"
    )
    reused: bool = Field(
        False, description="answered for a repeated upload (the same route, parameters and "
        "extractor as an earlier one): nothing new was queued",
    )
    progress: JobProgress = Field(default_factory=JobProgress, description="the fit's progress")

    @computed_field  # type: ignore[prop-decorator]
    @property
    def job_id(self) -> str:
        """The same as ``id``: the name the upload answer is documented with."""
        return self.id

    @property
    def done(self) -> bool:
        return self.state in TERMINAL_STATES

    @property
    def succeeded(self) -> bool:
        return self.state == "succeeded"


class JobPage(Answer):
    """``GET /v1/jobs``: one page of jobs."""

    jobs: list[Job] = Field(description="newest first")
    next_cursor: str | None = Field(None, description="pass as ?cursor= for the next page")

"""What the registry returns: maps, immutable versions and training jobs (pydantic)."""

from __future__ import annotations

from datetime import datetime
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field

JobState = Literal["queued", "running", "succeeded", "failed"]
JOB_STATES: tuple[str, ...] = ("queued", "running", "succeeded", "failed")
TERMINAL_STATES: frozenset[str] = frozenset({"succeeded", "failed"})


class VersionInfo(BaseModel):
    """One immutable trained version of a map."""

    model_config = ConfigDict(frozen=True)

    map: str
    version: int
    active: bool
    n_frames: int
    n_features: int
    kind: str
    params: dict[str, Any]
    extractor: dict[str, Any] | None
    created_at: datetime
    sha256: str = Field(description="sha256 of the artifact's tensors file")
    footprint: dict[str, Any] = Field(description="paper_bytes, actual_bytes, components")
    artifact_bytes: int
    metrics: dict[str, Any]
    job_id: str | None
    content_sha256: str | None = Field(
        None, description="sha256 of the uploaded route's descriptors (float32 .npy)"
    )
    extra: dict[str, Any] = Field(
        default_factory=dict,
        description="further metadata, e.g. dimension_change {from, to, reference_version}",
    )


class MapInfo(BaseModel):
    model_config = ConfigDict(frozen=True)

    name: str
    active_version: int | None
    versions: list[int]
    created_at: datetime


class JobRetry(BaseModel):
    """One part of a job that failed and was queued again."""

    model_config = ConfigDict(frozen=True)

    part: str = Field(description="e.g. chunk-3, classifier, prepare, train")
    attempt: int = Field(description="the attempt that failed (1 = the first run)")
    error: str
    at: datetime


class JobInfo(BaseModel):
    """A training job's externally visible state."""

    model_config = ConfigDict(frozen=True)

    id: str
    map: str
    state: JobState
    stage: str
    chunks_done: int
    chunks_total: int
    created_at: datetime
    started_at: datetime | None
    finished_at: datetime | None
    error: str | None
    version: int | None
    idempotency_key: str | None
    timings: dict[str, float]
    content_sha256: str | None = None
    retries: list[JobRetry] = Field(
        default_factory=list, description="parts that failed and were run again, oldest first"
    )
    reused: bool = Field(
        False, description="answered for a repeated upload (the same route, parameters and "
        "extractor as an earlier one): nothing new was queued",
    )

    @property
    def done(self) -> bool:
        return self.state in TERMINAL_STATES


class RouteSource(BaseModel):
    """What was uploaded, for recognising a repeated upload and a change of descriptor width."""

    model_config = ConfigDict(frozen=True)

    content_sha256: str = Field(description="sha256 of the stored float32 descriptors")
    n_frames: int
    n_features: int
    allow_dimension_change: bool = False


class JobSpec(BaseModel):
    """What a job trains (kept with the job so any worker process can run it)."""

    model_config = ConfigDict(frozen=True)

    job_id: str
    map: str
    route: str = Field(description="route .npy path, relative to data_dir when inside it")
    params: dict[str, Any]
    extractor: dict[str, Any] | None
    backend: str
    owner: str | None = None
    source: RouteSource | None = None


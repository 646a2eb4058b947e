"""What the registry returns: maps, immutable versions and training jobs.

Maps, versions and jobs are returned as the API's wire models (:mod:`service.wire`) under the
registry's names, so the admin API serves them as they are; :class:`RouteSource` and
:class:`JobSpec` (what a worker needs to run a job) are the registry's own.
"""

from __future__ import annotations

from typing import Any

from pydantic import BaseModel, ConfigDict, Field

from service.wire import JOB_STATES, TERMINAL_STATES, JobRetry, JobState
from service.wire import Job as JobInfo
from service.wire import MapSummary as MapInfo
from service.wire import Version as VersionInfo

__all__ = ["JOB_STATES", "TERMINAL_STATES", "JobInfo", "JobRetry", "JobSpec", "JobState",
           "MapInfo", "RouteSource", "VersionInfo"]  # fmt: skip


class RouteSource(BaseModel):
    """What was uploaded, for recognising a repeated upload and a change of descriptor width."""

    model_config = ConfigDict(frozen=True)

    content_sha256: str = Field(
        description="sha256 of the stored float32 descriptors (of every traversal, and of "
        "their place index, when there are several)"
    )
    n_frames: int = Field(description="places on the route")
    n_features: int
    allow_dimension_change: bool = False
    n_traversals: int = Field(1, ge=1, description="traversals of the places uploaded")
    places: str | None = Field(
        None, description="int64 .npy of every route row's place, relative to data_dir when "
        "inside it; None: one traversal, row i is place i",
    )  # fmt: skip
    conditions: dict[str, list[tuple[int, int]]] = Field(
        default_factory=dict, description="condition key → the [start, stop) row ranges of "
        "its tagged traversals, whose statistics the trained model records (a retrain)",
    )  # fmt: skip
    lineage: list[dict[str, Any]] | None = Field(
        None, description="the traversals the route was gathered from (a retrain), recorded "
        "in the version's extra.traversals",
    )  # fmt: skip
    retrained_from: int | None = Field(None, description="the version a retrain started from")


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

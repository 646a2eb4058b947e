"""What a gridplace server answers, as pydantic models.

These mirror ``service/api/schemas.py`` rather than import it: the server's schemas pull in
the service layer (numpy models, the registry), and a client must install and import light.
Unknown fields are ignored, so a newer server does not break an older client.
"""

from __future__ import annotations

from datetime import datetime
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

JobState = Literal["queued", "running", "succeeded", "failed"]
TERMINAL_STATES: frozenset[str] = frozenset({"succeeded", "failed"})


class _Answer(BaseModel):
    model_config = ConfigDict(extra="ignore", frozen=True)


class Health(_Answer):
    status: str


class Readiness(_Answer):
    """``/readyz``: every map with an active version is loaded (``ready``) or not yet."""

    ready: bool
    generation: int | None = None
    loaded: dict[str, int] = Field(default_factory=dict, description="map → served version")
    pending: list[str] = Field(default_factory=list)
    errors: dict[str, str] = Field(default_factory=dict)


class Localization(_Answer):
    map: str
    version: int
    index: int = Field(description="frame index on the route")
    chunk: int
    confidence: float
    latency_ms: float


class BatchLocalization(_Answer):
    map: str
    version: int
    n: int
    index: list[int]
    chunk: list[int]
    confidence: list[float]
    latency_ms: float


class MapSummary(_Answer):
    name: str
    active_version: int | None
    versions: list[int]
    created_at: datetime


class Version(_Answer):
    map: str
    version: int
    active: bool
    n_frames: int
    n_features: int
    kind: str
    params: dict[str, Any]
    extractor: dict[str, Any] | None
    created_at: datetime
    sha256: str
    footprint: dict[str, Any]
    artifact_bytes: int
    metrics: dict[str, Any]
    job_id: str | None


class MapDetail(MapSummary):
    active: Version | None = None
    serving_version: int | None = None


class JobRetry(_Answer):
    part: str
    attempt: int
    error: str
    at: datetime


class Job(_Answer):
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
    timings: dict[str, float] = Field(default_factory=dict)
    content_sha256: str | None = None
    retries: list[JobRetry] = Field(default_factory=list)
    reused: bool = False

    @property
    def done(self) -> bool:
        return self.state in TERMINAL_STATES

    @property
    def succeeded(self) -> bool:
        return self.state == "succeeded"


class JobPage(_Answer):
    jobs: list[Job]
    next_cursor: str | None = None


class TrainingOptions(BaseModel):
    """The form fields of ``POST /v1/maps/{name}/routes``; ``None`` = the server's default.

    Validated here (unknown names are refused) so a typo fails before a large upload."""

    model_config = ConfigDict(extra="forbid")

    n_patterns: int | None = Field(default=None, ge=1)
    periods: list[int] | None = None
    rho: float | None = Field(default=None, gt=0.0, le=1.0)
    gamma: float | None = None
    trainer: Literal["logreg", "svm", "ridge", "torch"] | None = None
    C: float | None = Field(default=None, gt=0.0)
    decode: Literal["joint", "argmax"] | None = None
    beam_width: int | None = Field(default=None, ge=1)
    dtype: Literal["float64", "float32", "float16", "int8"] | None = None
    n_chunks: int | None = Field(default=None, ge=1)
    chunk_rho: float | None = Field(default=None, gt=0.0, le=1.0)
    top_chunks: int | None = Field(default=None, ge=1)
    random_state: int | None = None
    extractor: Literal["patchnorm", "hog", "cnn"] | None = None
    width: int | None = Field(default=None, ge=1)
    height: int | None = Field(default=None, ge=1)
    patch: int | None = Field(default=None, ge=1)
    orientations: int | None = Field(default=None, ge=1)
    pixels_per_cell: int | None = Field(default=None, ge=1)
    cells_per_block: int | None = Field(default=None, ge=1)
    arch: str | None = None
    weights: str | None = Field(default=None, description="a path on the server")
    allow_dimension_change: bool | None = Field(
        default=None, description="accept another descriptor width than the active version's"
    )
    force: bool | None = Field(default=None, description="train a repeated upload again")

    @model_validator(mode="after")
    def _periods(self) -> TrainingOptions:
        if self.periods is not None and (not self.periods or min(self.periods) < 2):
            raise ValueError("periods must be integers >= 2")
        return self

    def form(self) -> dict[str, str]:
        """The multipart form fields (only the options that were set)."""
        out: dict[str, str] = {}
        for key, value in self.model_dump(exclude_none=True).items():
            if key == "periods":
                out[key] = ",".join(str(p) for p in value)
            else:
                out[key] = str(value).lower() if isinstance(value, bool) else str(value)
        return out

"""Request and response bodies of the REST API (pydantic, documented in /docs)."""

from __future__ import annotations

from datetime import datetime
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, computed_field, model_validator

from service.core.localization import LocalizeResult

MapName = Field(..., description="map (route) name", examples=["nordland"])


class LocalizeRequest(BaseModel):
    """One query: exactly one of ``descriptor``, ``descriptor_b64`` or ``image_b64``."""

    model_config = ConfigDict(extra="forbid")

    map: str = MapName
    descriptor: list[float] | None = Field(None, description="d floats")
    descriptor_b64: str | None = Field(None, description="base64 of d little-endian float32")
    image_b64: str | None = Field(None, description="base64 of an encoded image (PNG, JPEG…)")

    @model_validator(mode="after")
    def _exactly_one(self) -> LocalizeRequest:
        given = [k for k in ("descriptor", "descriptor_b64", "image_b64") if getattr(self, k) is not None]
        if len(given) != 1:
            raise ValueError(
                "send exactly one of descriptor, descriptor_b64, image_b64"
                + (f" (got {', '.join(given)})" if given else "")
            )
        return self


class BatchLocalizeRequest(BaseModel):
    """Many queries: exactly one of ``descriptors``, ``descriptors_b64`` or ``images_b64``."""

    model_config = ConfigDict(extra="forbid")

    map: str = MapName
    descriptors: list[list[float]] | None = Field(None, description="n rows of d floats")
    descriptors_b64: str | None = Field(None, description="base64 of n·d little-endian float32")
    images_b64: list[str] | None = Field(None, description="base64 encoded images")

    @model_validator(mode="after")
    def _exactly_one(self) -> BatchLocalizeRequest:
        given = [k for k in ("descriptors", "descriptors_b64", "images_b64") if getattr(self, k) is not None]
        if len(given) != 1:
            raise ValueError(
                "send exactly one of descriptors, descriptors_b64, images_b64"
                + (f" (got {', '.join(given)})" if given else "")
            )
        return self


class LocalizeResponse(BaseModel):
    map: str
    version: int
    index: int = Field(..., description="frame index on the route")
    chunk: int = Field(..., description="chunk that answered (0 without chunking)")
    confidence: float = Field(..., ge=0.0, le=1.0)
    latency_ms: float = Field(..., description="server-side time in the service layer")

    @classmethod
    def of(cls, r: LocalizeResult) -> LocalizeResponse:
        return cls(map=r.map, version=r.version, index=int(r.index[0]), chunk=int(r.chunk[0]),
                   confidence=float(r.confidence[0]), latency_ms=r.latency_ms)  # fmt: skip


class BatchLocalizeResponse(BaseModel):
    map: str
    version: int
    n: int
    index: list[int]
    chunk: list[int]
    confidence: list[float]
    latency_ms: float

    @classmethod
    def of(cls, r: LocalizeResult) -> BatchLocalizeResponse:
        return cls(map=r.map, version=r.version, n=len(r), index=r.index.tolist(),
                   chunk=r.chunk.tolist(), confidence=r.confidence.tolist(),
                   latency_ms=r.latency_ms)  # fmt: skip


class _FromAttrs(BaseModel):
    model_config = ConfigDict(from_attributes=True)


class MapOut(_FromAttrs):
    name: str
    active_version: int | None
    versions: list[int]
    created_at: datetime


class VersionOut(_FromAttrs):
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
    content_sha256: str | None = Field(None, description="sha256 of the route's descriptors")
    extra: dict[str, Any] = Field(
        default_factory=dict, description="e.g. dimension_change {from, to, reference_version}"
    )


class MapDetail(MapOut):
    active: VersionOut | None = None
    serving_version: int | None = Field(None, description="version loaded in this process")


class JobRetryOut(_FromAttrs):
    part: str = Field(..., description="chunk-3, classifier, prepare, train or assemble")
    attempt: int = Field(..., description="the attempt that failed (1 = first run)")
    error: str
    at: datetime


class JobOut(_FromAttrs):
    id: str
    map: str
    state: Literal["queued", "running", "succeeded", "failed"]
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
    content_sha256: str | None = Field(None, description="sha256 of the uploaded descriptors")
    retries: list[JobRetryOut] = Field(
        default_factory=list, description="parts that failed and were run again, oldest first"
    )
    reused: bool = Field(
        False, description="an earlier upload's job (the same route, parameters and "
        "extractor): nothing new was queued",
    )

    @computed_field  # type: ignore[prop-decorator]
    @property
    def job_id(self) -> str:
        """The same as ``id``: the name the upload answer is documented with."""
        return self.id


class JobPage(BaseModel):
    jobs: list[JobOut] = Field(..., description="newest first")
    next_cursor: str | None = Field(None, description="pass as ?cursor= for the next page")


class ErrorOut(BaseModel):
    error: str = Field(..., description="machine-readable code, e.g. dimension_mismatch")
    message: str
    details: dict[str, Any] | None = None

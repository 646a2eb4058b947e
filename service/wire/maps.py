"""Maps and their immutable versions, as the admin API (and the registry) describe them."""

from __future__ import annotations

from datetime import datetime
from typing import Any

from pydantic import Field

from service.wire.base import Answer


class MapSummary(Answer):
    name: str
    active_version: int | None = Field(description="the version localize answers with")
    versions: list[int]
    created_at: datetime


class Version(Answer):
    """One immutable trained version of a map."""

    map: str
    version: int
    active: bool
    n_frames: int = Field(description="places on the route (the indices localize answers)")
    n_traversals: int = Field(
        1, description="traversals of the route's places the version was trained on"
    )
    n_features: int = Field(description="descriptor size d that queries must have")
    kind: str = Field(description="phase_encoder or chunked_encoder")
    params: dict[str, Any] = Field(description="the training parameters")
    extractor: dict[str, Any] | None = Field(description="image extractor config, if any")
    created_at: datetime
    sha256: str = Field(description="sha256 of the artifact's tensors file")
    footprint: dict[str, Any] = Field(description="paper_bytes, actual_bytes, components")
    artifact_bytes: int
    metrics: dict[str, Any]
    job_id: str | None = Field(description="the training job that produced it")
    content_sha256: str | None = Field(
        None, description="sha256 of the uploaded route's descriptors (float32 .npy)"
    )
    extra: dict[str, Any] = Field(
        default_factory=dict,
        description="further metadata, e.g. dimension_change {from, to, reference_version}",
    )


class MapDetail(MapSummary):
    active: Version | None = Field(None, description="the active version")
    serving_version: int | None = Field(None, description="version loaded in this process")

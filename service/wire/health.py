"""``/healthz`` and ``/readyz`` answers."""

from __future__ import annotations

from pydantic import Field

from service.wire.base import Answer


class Health(Answer):
    status: str = Field(description="'ok' while the process is alive")


class Readiness(Answer):
    """``/readyz`` (200 when ``ready``, else 503 with the same body)."""

    ready: bool = Field(description="every map with an active version has it loaded")
    generation: int | None = Field(None, description="registry generation last loaded")
    loaded: dict[str, int] = Field(default_factory=dict, description="map → served version")
    pending: list[str] = Field(default_factory=list, description="maps not loaded yet")
    errors: dict[str, str] = Field(default_factory=dict, description="map → why it failed to load")

"""``POST /v1/localize/sequence``: an ordered batch of frames as one drive, and its answer."""

from __future__ import annotations

from typing import Any

from pydantic import Field

from service.wire.base import Answer


class SequenceLocalization(Answer):
    """Per frame of one drive, the sequence filter's estimate and the frame's own answer."""

    map: str
    version: int = Field(description="the one map version that answered every frame")
    n: int = Field(description="frames in the drive")
    index: list[int] = Field(description="filtered estimate of each frame")
    chunk: list[int] = Field(description="chunk holding each filtered estimate")
    confidence: list[float] = Field(description="posterior mass near each estimate")
    speed: list[float] = Field(description="estimated speed, frames per query frame")
    raw_index: list[int] = Field(description="each frame's own answer (as /localize)")
    raw_confidence: list[float]
    filter: dict[str, Any] = Field(description="the filter parameters the server used")
    latency_ms: float

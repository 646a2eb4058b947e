"""``POST /v1/localize/sequence``: an ordered batch of frames as one drive, and its answer.

The filter options mirror :class:`service.encoding.sequence.SequenceConfig` (its static bounds;
a test keeps them equal): every option is optional, an unset one takes the server's default.
Rules that involve several options (``max_speed ≥ min_speed``, the size of the speed grid)
are checked by the server.
"""

from __future__ import annotations

from typing import Any, Literal

from pydantic import ConfigDict, Field, field_validator

from service.wire.base import Answer, Request, not_a_boolean
from service.wire.localize import BatchLocalizeRequest

EmissionMode = Literal["zscore", "raw"]


class SequenceFilterOptions(Request):
    """The sequence filter's parameters; ``None`` = the server's (measured) default."""

    model_config = ConfigDict(allow_inf_nan=False)

    min_speed: float | None = Field(
        None, ge=0.0, le=50.0, description="slowest speed, frames per query frame"
    )
    max_speed: float | None = Field(
        None, ge=0.0, le=50.0, description="fastest speed, frames per query frame"
    )
    speed_step: float | None = Field(None, gt=0.0, le=50.0, description="spacing of the speed grid")
    speed_change: float | None = Field(
        None, ge=0.0, le=1.0, description="probability per frame of moving to a neighbouring speed"
    )
    speed_jump: float | None = Field(
        None, ge=0.0, le=1.0,
        description="probability per frame of moving to any speed of the direction driven "
        "(abrupt speed changes, dropped frames; 0: speeds change only by neighbouring steps)",
    )
    reverse: bool | None = Field(None, description="the vehicle may drive the route backwards")
    direction_change: float | None = Field(
        None, ge=0.0, le=1.0, description="probability per frame of reversing (with reverse)"
    )
    stop_probability: float | None = Field(
        None, ge=0.0, le=0.5, description="probability per frame of stopping (0: no stopped state)"
    )
    start_probability: float | None = Field(
        None, gt=0.0, le=1.0, description="probability per frame that a stopped vehicle moves on"
    )
    relocalization: float | None = Field(
        None, gt=0.0, le=1.0, description="probability per frame of a jump anywhere on the route"
    )
    emission: EmissionMode | None = Field(
        None, description="zscore: standardise each query's frame scores; raw: use them as is"
    )
    emission_scale: float | None = Field(
        None, gt=0.0, le=1e3, description="weight of one query's evidence"
    )
    repeat_novelty: float | None = Field(
        None, ge=0.0, le=100.0,
        description="novelty of a frame's scores over the previous frame's, in one-frame moves, "
        "below which it repeats the previous view, softly (0: off, every frame is new evidence)",
    )
    repeat_speed: bool | None = Field(
        None,
        description="repeats and new views are also evidence of the speed (repeat_stopped, "
        "repeat_moving, move_novelty); off: a repeat only tempers a stopped state's evidence",
    )
    move_novelty: float | None = Field(
        None, ge=0.0, le=100.0,
        description="novelty from which a frame is a new view, evidence of moving (half of it "
        "and below: no evidence either way, unless a repeat; 0: every frame that is no repeat)",
    )
    repeat_stopped: float | None = Field(
        None, gt=0.0, lt=1.0,
        description="probability that a stopped vehicle's frame repeats the previous view",
    )
    repeat_moving: float | None = Field(
        None, gt=0.0, lt=1.0,
        description="probability that a vehicle moving a frame or more per frame repeats its view",
    )
    confidence_radius: int | None = Field(
        None, ge=0, le=10_000, description="confidence = posterior mass within this many frames"
    )
    odometry_noise: float | None = Field(
        None, ge=0.0, le=10.0,
        description="odometry's standard deviation as a fraction of the displacement",
    )
    odometry_floor: float | None = Field(
        None, ge=0.0, le=1_000.0,
        description="odometry's standard deviation in frames at any displacement",
    )
    tracking: bool | None = Field(
        None, description="once localised, update only windows around the belief"
    )
    track_radius: int | None = Field(
        None, ge=4, le=100_000, description="half width of a tracking window, frames"
    )
    tracking_mass: float | None = Field(
        None, gt=0.5, lt=1.0,
        description="posterior mass within track_radius of the estimate that starts tracking",
    )
    check_every: int | None = Field(
        None, ge=1, le=1_000, description="frames between global checks for other places"
    )
    candidates: int | None = Field(
        None, ge=1, le=16, description="places a global check may open windows at"
    )
    window_frames: int | None = Field(
        None, ge=8, le=1_000_000,
        description="route frames a tracker's windows may cover together (on weak evidence)",
    )
    whole_route_budget: int | None = Field(
        None, ge=1, le=1_000_000_000,
        description="state updates per frame, on average, a tracker may spend on the whole route",
    )

    _numbers = field_validator(
        "min_speed", "max_speed", "speed_step", "speed_change", "speed_jump", "direction_change",
        "stop_probability", "start_probability", "relocalization", "emission_scale",
        "repeat_novelty", "move_novelty", "repeat_stopped", "repeat_moving",
        "confidence_radius", mode="before",
    )(not_a_boolean)  # fmt: skip

    def given(self) -> dict[str, Any]:
        """The options that were set (the rest take the server's defaults)."""
        return self.model_dump(exclude_none=True)


class SequenceLocalizeRequest(BatchLocalizeRequest):
    """A drive: exactly one of ``descriptors``, ``descriptors_b64`` or ``images_b64`` (rows in
    driving order), and optionally the filter's options."""

    filter: SequenceFilterOptions | None = Field(None, description="sequence filter options")
    odometry: list[float | None] | None = Field(
        None, description="per frame, the vehicle's measured displacement along the route since "
        "the previous frame, in reference frames (signed; null for a frame without): the "
        "filter's motion model centres on it. One entry per frame",
    )  # fmt: skip
    odometry_m: list[float | None] | None = Field(
        None, description="as odometry, in metres: divided by the map's frame spacing recorded "
        "at upload (frame_spacing_m; 409 when the map has none)",
    )  # fmt: skip
    adaptation: bool | None = Field(
        None, description="standardise each frame by the running statistics of the drive's "
        "earlier frames first (appearance adaptation); unset: the server's default "
        "(GRIDPLACE_DRIVE_ADAPTATION, on unless configured off)",
    )  # fmt: skip


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
    filter: dict[str, Any] = Field(description="every filter parameter the server used")
    latency_ms: float
    adapted: bool = Field(False, description="the drive's frames were adapted (appearance adaptation)")
    condition: str | None = Field(
        None, description="the condition the drive was standardised from (adapted: the one "
        "its running statistics started from, named or inferred from its first frames)",
    )

"""The building blocks every wire model shares: the two base classes and the field types."""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field

MAP_NAME_PATTERN = r"^[a-z0-9][a-z0-9_.-]{0,63}$"
MAX_VERSION = 2**63 - 1  # versions are SQLite INTEGERs

MapName = Annotated[str, Field(pattern=MAP_NAME_PATTERN, description="map (route) name",
                               examples=["nordland"])]  # fmt: skip
VersionNumber = Annotated[int, Field(ge=1, le=MAX_VERSION, description="a map version (1, 2, …)")]


def not_a_boolean(value: Any) -> Any:
    """A ``mode="before"`` validator of a number field that may also come as text (query
    strings): pydantic's lax mode would read JSON ``true`` as 1."""
    if isinstance(value, bool):
        raise ValueError("a boolean is not a number")
    return value


# a descriptor value in a JSON body: a number, never true/false or a string
DescriptorValue = Annotated[float, Field(strict=True)]
JobState = Literal["queued", "running", "succeeded", "failed"]
JOB_STATES: tuple[str, ...] = ("queued", "running", "succeeded", "failed")
TERMINAL_STATES: frozenset[str] = frozenset({"succeeded", "failed"})


class Answer(BaseModel):
    """A body the server sends. Unknown fields are ignored (a newer server does not break an
    older client); attributes are read from any object (the server validates its registry and
    service-layer objects directly)."""

    model_config = ConfigDict(extra="ignore", frozen=True, from_attributes=True)


class Request(BaseModel):
    """A body a client sends. Unknown fields are refused, so a typo is an error naming it."""

    model_config = ConfigDict(extra="forbid")


def exactly_one_of(*fields: str) -> dict[str, Any]:
    """JSON-schema ``oneOf`` saying that exactly one of ``fields`` is present and not null
    (add it with ``json_schema_extra``; the model's validator enforces the same rule)."""

    def one(name: str) -> dict[str, Any]:
        return {"required": [name], "properties": {name: {"not": {"type": "null"}}}}

    return {"oneOf": [one(f) for f in fields]}


def given(model: BaseModel, fields: tuple[str, ...]) -> list[str]:
    """The names among ``fields`` whose value is not None."""
    return [f for f in fields if getattr(model, f) is not None]

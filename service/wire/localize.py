"""``POST /v1/localize`` and ``POST /v1/localize/batch`` JSON bodies and answers."""

from __future__ import annotations

import re
from typing import Annotated

from pydantic import AfterValidator, ConfigDict, Field, model_validator

from service.wire.base import Answer, DescriptorValue, MapName, Request, exactly_one_of, given

_B64 = "[A-Za-z0-9+/]"
BASE64_PATTERN = rf"^(?:{_B64}{{4}})*(?:{_B64}{{2}}==|{_B64}{{3}}=)?$"
# base64 of a whole number of float32 values: 3 float32 = 12 bytes = 16 characters
FLOAT32_BASE64_PATTERN = rf"^(?:{_B64}{{16}})*(?:{_B64}{{6}}==|{_B64}{{11}}=)?$"
_BASE64 = re.compile(BASE64_PATTERN)
VEHICLE_KEY_PATTERN = r"^[A-Za-z0-9_-]{22,128}$"


def _base64(text: str) -> str:
    if not _BASE64.fullmatch(text):
        raise ValueError("not valid base64 (A-Z a-z 0-9 + / in groups of 4, '=' padding)")
    return text


def _float32_base64(text: str) -> str:
    _base64(text)
    n_bytes = len(text) // 4 * 3 - text[-2:].count("=")
    if n_bytes % 4:
        raise ValueError(f"base64 of {n_bytes} bytes, not a whole number of float32 values")
    return text


# the pattern is in the schema; the validators say in words what a mismatch means
Base64 = Annotated[str, Field(min_length=1, json_schema_extra={"pattern": BASE64_PATTERN}),
                   AfterValidator(_base64)]  # fmt: skip
Float32Base64 = Annotated[str, Field(min_length=1, json_schema_extra={"pattern": FLOAT32_BASE64_PATTERN}),
                          AfterValidator(_float32_base64)]  # fmt: skip
QUERY_FIELDS = ("descriptor", "descriptor_b64", "image_b64")
BATCH_FIELDS = ("descriptors", "descriptors_b64", "images_b64")


def _exactly_one(model: Request, fields: tuple[str, ...]) -> None:
    sent = given(model, fields)
    if len(sent) != 1:
        raise ValueError(
            f"send exactly one of {', '.join(fields)}" + (f" (got {', '.join(sent)})" if sent else "")
        )


CONDITION_DOC = (
    "the condition the query was taken in: a condition the version recorded from tagged "
    "traversals (key=value tags sorted by key and joined by ',', e.g. season=winter), "
    "'reference' (the route's own), or 'auto' (inferred from the frames). A query outside "
    "an adapted drive (single, batch, unadapted) is standardised by its statistics; an "
    "adapted drive (a vehicle's queries, a sequence, a stream's vehicle) starts its running "
    "statistics from them. Unset: single queries and batches as sent; an adapted drive "
    "infers it from its first frames (GRIDPLACE_CONDITION_FRAMES) when the version records "
    "conditions. One the version does not record: 400 unknown_condition naming the known ones"
)
Condition = Annotated[str | None, Field(min_length=1, max_length=4096, description=CONDITION_DOC,
                                        examples=["season=winter"])]  # fmt: skip


class VehicleOptions(Request):
    """Who sends a query, for appearance adaptation (also the form fields of an image query)."""

    condition: Condition = None

    vehicle_id: str | None = Field(
        None, min_length=1, max_length=128,
        description="the sending vehicle: its queries are adapted to its own earlier ones "
        "(appearance adaptation) unless adaptation is false",
    )
    adaptation: bool | None = Field(
        None, description="appearance adaptation (needs vehicle_id); unset: the server's "
        "default (GRIDPLACE_DRIVE_ADAPTATION) when a vehicle_id is given",
    )
    vehicle_key: str | None = Field(
        None, pattern=VEHICLE_KEY_PATTERN,
        description="the vehicle's credential: its statistics are kept under vehicle_id and "
        "this key, so only a caller that knows it continues (or resets) them. Unset: the "
        "server issues a new key (a new drive) and answers it; send it with the vehicle's "
        "later queries. A caller may also choose its own (22–128 random characters of "
        "A-Z a-z 0-9 _ -)",
    )
    reset: bool | None = Field(
        None, description="forget the vehicle's statistics (vehicle_id + vehicle_key) before "
        "this query, e.g. at the start of a new traversal",
    )


class LocalizeRequest(VehicleOptions):
    """One query: exactly one of ``descriptor``, ``descriptor_b64`` or ``image_b64``."""

    model_config = ConfigDict(json_schema_extra=exactly_one_of(*QUERY_FIELDS))

    map: MapName
    descriptor: list[DescriptorValue] | None = Field(None, min_length=1, description="d floats")
    descriptor_b64: Float32Base64 | None = Field(None, description="base64 of d little-endian float32")
    image_b64: Base64 | None = Field(None, description="base64 of an encoded image (PNG, JPEG…)")

    @model_validator(mode="after")
    def _one_query(self) -> LocalizeRequest:
        _exactly_one(self, QUERY_FIELDS)
        return self


class BatchLocalizeRequest(Request):
    """Many queries: exactly one of ``descriptors``, ``descriptors_b64`` or ``images_b64``."""

    model_config = ConfigDict(json_schema_extra=exactly_one_of(*BATCH_FIELDS))

    map: MapName
    condition: Condition = None
    descriptors: list[list[DescriptorValue]] | None = Field(None, min_length=1,
                                                  description="n rows of d floats")  # fmt: skip
    descriptors_b64: Float32Base64 | None = Field(None,
                                                  description="base64 of n·d little-endian float32")  # fmt: skip
    images_b64: list[Base64] | None = Field(None, min_length=1,
                                            description="base64 encoded images")  # fmt: skip

    @model_validator(mode="after")
    def _one_query(self) -> BatchLocalizeRequest:
        _exactly_one(self, BATCH_FIELDS)
        return self


class Localization(Answer):
    map: str
    version: int = Field(description="the map version that answered")
    index: int = Field(description="frame index on the route")
    chunk: int = Field(description="chunk that answered (0 without chunking)")
    confidence: float = Field(ge=0.0, le=1.0)
    latency_ms: float = Field(description="server-side time in the service layer")
    adapted: bool = Field(False, description="the query was adapted to the vehicle's earlier ones")
    condition: str | None = Field(
        None, description="the condition the query was standardised from (a vehicle's: the "
        "one its drive started from, named or inferred); unset when none was named or used",
    )
    vehicle_key: str | None = Field(
        None, description="the key the vehicle's statistics are kept under (set when they "
        "were): send it with the vehicle's next query",
    )


class BatchLocalization(Answer):
    map: str
    version: int
    n: int = Field(description="number of queries answered")
    index: list[int]
    chunk: list[int]
    confidence: list[float]
    latency_ms: float
    condition: str | None = Field(None, description="the condition the queries were "
                                  "standardised from (named, or inferred from them all)")  # fmt: skip

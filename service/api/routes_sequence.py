"""``POST /v1/localize/sequence``: an ordered batch of frames localized as one drive.

The same bodies as ``/v1/localize/batch`` (JSON descriptors, base64 float32, base64 images, a
multipart form of images, or a raw little-endian float32 body), rows in driving order. The
answer holds, per frame, the sequence filter's estimate and the frame's own answer. Filter
parameters (:class:`~service.encoding.sequence.SequenceConfig`) come as the JSON body's
``filter`` object, or as query parameters (any body); each has a validated range and a
measured default.
"""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, Header, Query, Request
from pydantic import BaseModel, ConfigDict, Field
from starlette.concurrency import run_in_threadpool

from service.api.routes_localize import (
    _IMAGES_FORM,
    ERRORS,
    _b64,
    _body_doc,
    _form,
    _json_body,
    _service,
    binary_map,
)
from service.api.schemas import BatchLocalizeRequest
from service.core.sequences import SequenceLocalizer, SequenceResult
from service.encoding.sequence import SequenceConfig
from service.errors import EmptyInputError, InvalidInputError

router = APIRouter(prefix="/v1", tags=["localize"])

_TRANSPORT_PARAMS = frozenset({"map", "d"})
FILTER_PARAMS = tuple(SequenceConfig.model_fields)


class SequenceLocalizeRequest(BatchLocalizeRequest):
    """A drive: exactly one of ``descriptors``, ``descriptors_b64`` or ``images_b64`` (rows in
    driving order), and optionally the filter's parameters."""

    model_config = ConfigDict(extra="forbid")

    filter: SequenceConfig | None = Field(None, description="sequence filter parameters")


class SequenceLocalizeResponse(BaseModel):
    map: str
    version: int = Field(..., description="the one map version that answered every frame")
    n: int
    index: list[int] = Field(..., description="filtered estimate of each frame")
    chunk: list[int] = Field(..., description="chunk holding each filtered estimate")
    confidence: list[float] = Field(..., description="posterior mass near each estimate")
    speed: list[float] = Field(..., description="estimated speed, frames per query frame")
    raw_index: list[int] = Field(..., description="each frame's own answer (as /localize)")
    raw_confidence: list[float]
    filter: SequenceConfig = Field(..., description="the filter parameters used")
    latency_ms: float

    @classmethod
    def of(cls, r: SequenceResult) -> SequenceLocalizeResponse:
        return cls(
            map=r.map,
            version=r.version,
            n=len(r),
            index=r.index.tolist(),
            chunk=r.chunk.tolist(),
            confidence=r.confidence.tolist(),
            speed=r.speed.tolist(),
            raw_index=r.raw_index.tolist(),
            raw_confidence=r.raw_confidence.tolist(),
            filter=r.config,
            latency_ms=r.latency_ms,
        )


def _query_filter(request: Request) -> dict[str, str]:
    """Filter parameters given in the query string (unknown names are a 400)."""
    given = {k: v for k, v in request.query_params.items() if k not in _TRANSPORT_PARAMS}
    unknown = sorted(set(given) - set(FILTER_PARAMS))
    if unknown:
        raise InvalidInputError(
            f"unknown query parameter(s) {', '.join(unknown)}; filter parameters are "
            f"{', '.join(FILTER_PARAMS)}",
            unknown=unknown,
        )
    return given


def _filter_doc() -> list[dict[str, Any]]:
    schema = SequenceConfig.model_json_schema()["properties"]
    return [
        {
            "name": k,
            "in": "query",
            "required": False,
            "description": f"{v.get('description', '')} (default {v.get('default')})",
            "schema": {
                key: v[key]
                for key in ("type", "enum", "minimum", "maximum", "exclusiveMinimum")
                if key in v
            },
        }
        for k, v in schema.items()
    ]


_DOC = _body_doc(SequenceLocalizeRequest, _IMAGES_FORM, binary=True)
_DOC["parameters"] = _filter_doc()


@router.post(
    "/localize/sequence",
    response_model=SequenceLocalizeResponse,
    responses=ERRORS,
    openapi_extra=_DOC,
    summary="Localize an ordered batch of frames as one drive (sequence filter)",
)
async def localize_sequence(
    request: Request,
    map_q: Annotated[str | None, Query(alias="map", description="map (binary bodies)")] = None,
    d_q: Annotated[
        int | None, Query(alias="d", ge=1, description="descriptor size (binary)")
    ] = None,
    map_h: Annotated[str | None, Header(alias="X-Gridplace-Map")] = None,
    d_h: Annotated[int | None, Header(alias="X-Gridplace-Dim", ge=1)] = None,
) -> SequenceLocalizeResponse:
    """JSON ``{"map", "descriptors" | "descriptors_b64" | "images_b64", "filter"?}``, a
    multipart form (``map`` + ``images`` files), or an ``application/octet-stream`` body of
    float32; frames in driving order. Each request is one drive: the filter starts afresh."""
    localizer = SequenceLocalizer(_service(request))
    query = _query_filter(request)
    ctype = request.headers.get("content-type", "")
    if ctype.startswith("application/octet-stream"):
        name = binary_map(map_q, map_h, "sequences")
        body = await request.body()
        result = await run_in_threadpool(
            localizer.localize_bytes, name, body, d_q or d_h, SequenceConfig(**query)
        )
    elif ctype.startswith("multipart/form-data"):
        name, images = await _form(request)
        result = await run_in_threadpool(
            localizer.localize_images, name, images, SequenceConfig(**query)
        )
    else:
        req = SequenceLocalizeRequest.model_validate_json(await _json_body(request))
        if req.filter is not None and query:
            raise InvalidInputError(
                "give the filter parameters in the body's 'filter' or in the query, not both"
            )
        config = req.filter if req.filter is not None else SequenceConfig(**query)
        result = await run_in_threadpool(_localize_drive, localizer, req, config)
    return SequenceLocalizeResponse.of(result)


def _localize_drive(
    localizer: SequenceLocalizer, req: SequenceLocalizeRequest, config: SequenceConfig
) -> SequenceResult:
    if req.images_b64 is not None:
        blobs = [
            (f"images_b64[{i}]", _b64(t, f"images_b64[{i}]")) for i, t in enumerate(req.images_b64)
        ]
        return localizer.localize_images(req.map, blobs, config)
    if req.descriptors_b64 is not None:
        return localizer.localize_bytes(
            req.map, _b64(req.descriptors_b64, "descriptors_b64"), None, config
        )
    assert req.descriptors is not None
    if not req.descriptors:
        raise EmptyInputError("descriptors is an empty list")
    if len({len(row) for row in req.descriptors}) != 1:
        raise InvalidInputError("descriptors rows have different lengths")
    return localizer.localize(req.map, req.descriptors, config)

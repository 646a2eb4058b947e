"""``POST /v1/localize/sequence``: an ordered batch of frames localized as one drive.

The same bodies as ``/v1/localize/batch`` (JSON descriptors, base64 float32, base64 images, a
multipart form of images, or a raw little-endian float32 body), rows in driving order. The
answer holds, per frame, the sequence filter's estimate and the frame's own answer. Filter
options (:class:`~service.wire.SequenceFilterOptions`, the server-side rules of
:class:`~service.encoding.sequence.SequenceConfig`) come as the JSON body's ``filter``
object or as query parameters (any body); each has a validated range and a measured default.
"""

from __future__ import annotations

import functools
from typing import Annotated, Any

from fastapi import APIRouter, Header, Query, Request

from service.api.cancellation import run_until_disconnected
from service.api.routes_localize import _b64, _form, _json_body, _service, binary_map
from service.api.schemas import ERRORS, IMAGES_FORM, ConditionParam, DimParam, MapParam, body_doc
from service.core.request_work import Cancellation
from service.core.sequences import SequenceLocalizer, SequenceResult
from service.encoding.sequence import SequenceConfig
from service.errors import EmptyInputError, InvalidInputError
from service.wire import SequenceFilterOptions, SequenceLocalization, SequenceLocalizeRequest
from service.wire.localize import CONDITION_DOC

router = APIRouter(prefix="/v1", tags=["localize"])

_TRANSPORT_PARAMS = frozenset({"map", "d", "adaptation", "condition"})
FILTER_PARAMS = tuple(SequenceFilterOptions.model_fields)


def sequence_localization(r: SequenceResult) -> SequenceLocalization:
    return SequenceLocalization(
        map=r.map, version=r.version, n=len(r), index=r.index.tolist(), chunk=r.chunk.tolist(),
        confidence=r.confidence.tolist(), speed=r.speed.tolist(), raw_index=r.raw_index.tolist(),
        raw_confidence=r.raw_confidence.tolist(), filter=r.config.model_dump(),
        latency_ms=r.latency_ms, adapted=r.adapted, condition=r.condition,
    )  # fmt: skip


def _config(options: SequenceFilterOptions | dict[str, Any] | None) -> SequenceConfig:
    """The filter configuration: the options given over the server's defaults. An option out
    of its static bounds is a 422 (the schema says so); options the schema allows but that
    break a rule across options (max_speed below min_speed, too many grid speeds) are a 400."""
    if isinstance(options, dict):
        options = SequenceFilterOptions(**options)
    return SequenceConfig.parse(**(options.given() if options is not None else {}))


def _query_filter(request: Request) -> dict[str, str]:
    """Filter options given in the query string (unknown names are a 400)."""
    given = {k: v for k, v in request.query_params.items() if k not in _TRANSPORT_PARAMS}
    unknown = sorted(set(given) - set(FILTER_PARAMS))
    if unknown:
        raise InvalidInputError(
            f"unknown query parameter(s) {', '.join(unknown)}; filter options are "
            f"{', '.join(FILTER_PARAMS)}",
            unknown=unknown,
        )
    return given


def _filter_doc() -> list[dict[str, Any]]:
    """The filter options as documented query parameters, with the server's defaults."""
    defaults = SequenceConfig()
    out = []
    for name, prop in SequenceFilterOptions.model_json_schema()["properties"].items():
        schema = next((v for v in prop.get("anyOf", [prop]) if v.get("type") != "null"), prop)
        out.append({"name": name, "in": "query", "required": False,
                    "description": f"{prop.get('description', '')} (default {getattr(defaults, name)})",
                    "schema": schema})  # fmt: skip
    return out


_DOC = body_doc(SequenceLocalizeRequest, IMAGES_FORM,
                binary="n·d little-endian float32, frames in driving order; the map as ?map= "
                       "(required), d as ?d=")  # fmt: skip
_DOC["parameters"] = _filter_doc()


@router.post(
    "/localize/sequence",
    response_model=SequenceLocalization,
    responses=ERRORS,
    openapi_extra=_DOC,
    summary="Localize an ordered batch of frames as one drive (sequence filter)",
)
async def localize_sequence(
    request: Request,
    map_q: Annotated[MapParam, Query(alias="map", description="the map (binary bodies)")] = None,
    d_q: Annotated[DimParam, Query(alias="d", description="descriptor size (binary)")] = None,
    map_h: Annotated[
        MapParam, Header(alias="X-Gridplace-Map", description="or the map here")
    ] = None,
    d_h: Annotated[DimParam, Header(alias="X-Gridplace-Dim", description="or d here")] = None,
    adaptation: Annotated[bool | None, Query(
        description="appearance adaptation (binary and form bodies; JSON: the body's field); "
                    "unset: the server's default")] = None,
    condition_q: Annotated[ConditionParam, Query(alias="condition", description=(
        "the drive's condition (binary and form bodies; JSON: the body's field): "
        + CONDITION_DOC))] = None,  # fmt: skip
) -> SequenceLocalization:
    """JSON ``{"map", "descriptors" | "descriptors_b64" | "images_b64", "filter"?}``, a
    multipart form (``map`` + ``images`` files), or an ``application/octet-stream`` body of
    float32; frames in driving order. Each request is one drive: the filter starts afresh."""
    localizer = SequenceLocalizer(_service(request))
    query = _query_filter(request)
    ctype = request.headers.get("content-type", "")
    if ctype.startswith("application/octet-stream"):
        name = binary_map(map_q, map_h, "sequences")
        body = await request.body()
        config = _config(query)
        result = await run_until_disconnected(request, lambda c: localizer.localize_bytes(
            name, body, d_q or d_h, config, adaptation, cancellation=c,
            condition=condition_q))  # fmt: skip
    elif ctype.startswith("multipart/form-data"):
        name, images, given = await _form(request, ("condition",))
        config = _config(query)
        condition = given.get("condition", condition_q)
        result = await run_until_disconnected(request, lambda c: localizer.localize_images(
            name, images, config, adaptation, cancellation=c, condition=condition))  # fmt: skip
    else:
        req = SequenceLocalizeRequest.model_validate_json(await _json_body(request))
        if req.filter is not None and query:
            raise InvalidInputError(
                "give the filter options in the body's 'filter' or in the query, not both"
            )
        if req.adaptation is not None and adaptation is not None:
            raise InvalidInputError(
                "give adaptation in the body or in the query, not both"
            )
        if req.condition is not None and condition_q is not None:
            raise InvalidInputError("give condition in the body or in the query, not both")
        config = _config(req.filter if req.filter is not None else query)
        if condition_q is not None:
            req = req.model_copy(update={"condition": condition_q})
        adapt = req.adaptation if req.adaptation is not None else adaptation
        result = await run_until_disconnected(
            request, functools.partial(_localize_drive, localizer, req, config, adapt))
    return sequence_localization(result)


def _localize_drive(
    localizer: SequenceLocalizer, req: SequenceLocalizeRequest, config: SequenceConfig,
    adapt: bool | None, cancellation: Cancellation,
) -> SequenceResult:  # fmt: skip
    if req.images_b64 is not None:
        blobs = [
            (f"images_b64[{i}]", _b64(t, f"images_b64[{i}]")) for i, t in enumerate(req.images_b64)
        ]
        return localizer.localize_images(req.map, blobs, config, adapt, req.odometry,
                                         req.odometry_m, cancellation, req.condition)  # fmt: skip
    if req.descriptors_b64 is not None:
        data = _b64(req.descriptors_b64, "descriptors_b64")
        return localizer.localize_bytes(req.map, data, None, config, adapt, req.odometry,
                                        req.odometry_m, cancellation, req.condition)  # fmt: skip
    assert req.descriptors is not None
    if not req.descriptors:
        raise EmptyInputError("descriptors is an empty list")
    if len({len(row) for row in req.descriptors}) != 1:
        raise InvalidInputError("descriptors rows have different lengths")
    return localizer.localize(req.map, req.descriptors, config, adapt, req.odometry,
                              req.odometry_m, cancellation, req.condition)  # fmt: skip

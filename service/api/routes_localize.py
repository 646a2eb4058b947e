"""``POST /v1/localize`` and ``POST /v1/localize/batch``: descriptors or images → frame index.

Requests are validated by the wire schemas (which also document them in ``/docs``); answers
are written with orjson straight from the result arrays (the fields of ``Localization`` and
``BatchLocalization``), without a second pydantic pass. Single descriptors go to the
micro-batcher shared with gRPC; batches, images and a server without batcher run on the
thread pool.
"""

from __future__ import annotations

import base64
import binascii
import time
from typing import Annotated

import orjson
from fastapi import APIRouter, Header, Query, Request, Response
from starlette.concurrency import run_in_threadpool
from starlette.datastructures import UploadFile

from service.api.schemas import (
    ERRORS,
    IMAGE_FORM,
    IMAGES_FORM,
    ConditionParam,
    DimParam,
    MapParam,
    body_doc,
)
from service.core.localization import LocalizationService, LocalizeResult, decode_float32
from service.core.streams import one_descriptor
from service.core.vehicle_adapters import answer_vehicle
from service.encoding import check_descriptors
from service.errors import EmptyInputError, InvalidInputError
from service.wire import (
    BatchLocalization,
    BatchLocalizeRequest,
    Localization,
    LocalizeRequest,
    VehicleOptions,
)
from service.wire.localize import CONDITION_DOC

router = APIRouter(prefix="/v1", tags=["localize"])
VEHICLE_FIELDS = ("vehicle_id", "adaptation", "vehicle_key", "reset", "condition")


def _b64(text: str, field: str) -> bytes:
    try:
        data = base64.b64decode(text, validate=True)
    except (binascii.Error, ValueError) as exc:
        raise InvalidInputError(f"{field} is not valid base64: {exc}", field=field) from exc
    if not data:
        raise EmptyInputError(f"{field} is empty")
    return data


def _service(request: Request) -> LocalizationService:
    return request.app.state.context.service  # type: ignore[no-any-return]


def _one(result: LocalizeResult, vehicle_key: str | None = None) -> Response:
    """:class:`~service.wire.Localization` as JSON (``vehicle_key`` when a vehicle's
    statistics are kept under one)."""
    body = {
        "map": result.map, "version": result.version, "index": int(result.index[0]),
        "chunk": int(result.chunk[0]), "confidence": float(result.confidence[0]),
        "latency_ms": result.latency_ms, "adapted": result.adapted,
    }  # fmt: skip
    if result.condition is not None:
        body["condition"] = result.condition
    if vehicle_key is not None:
        body["vehicle_key"] = vehicle_key
    return Response(orjson.dumps(body), media_type="application/json")


def _many(result: LocalizeResult) -> Response:
    """:class:`~service.wire.BatchLocalization` as JSON (arrays serialised by orjson)."""
    return Response(orjson.dumps({
        "map": result.map, "version": result.version, "n": len(result),
        "index": result.index, "chunk": result.chunk, "confidence": result.confidence,
        "latency_ms": result.latency_ms,
        **({} if result.condition is None else {"condition": result.condition}),
    }, option=orjson.OPT_SERIALIZE_NUMPY), media_type="application/json")  # fmt: skip


async def _form(request: Request, fields: tuple[str, ...] = ()
                ) -> tuple[str, list[tuple[str, bytes]], dict[str, str]]:  # fmt: skip
    """``map``, the image files and the text ``fields`` given of a multipart form."""
    form = await request.form()
    name = form.get("map")
    if not isinstance(name, str) or not name:
        raise InvalidInputError("multipart localize needs a 'map' form field", field="map")
    images = []
    for key, value in form.multi_items():
        if isinstance(value, UploadFile):
            images.append((value.filename or key, await value.read()))
    if not images:
        raise EmptyInputError("multipart localize needs an image file field ('image')")
    given = {f: v for f in fields if isinstance(v := form.get(f), str)}
    return name, images, given


def binary_map(map_q: str | None, map_h: str | None, what: str) -> str:
    """The map of a binary body: the ``map`` query parameter or the ``X-Gridplace-Map`` header."""
    name = map_q or map_h
    if not name:
        raise InvalidInputError(
            f"binary {what} need the map as ?map=NAME or an X-Gridplace-Map header", field="map"
        )
    return name


async def _json_body(request: Request) -> bytes:
    body = await request.body()
    if not body.strip():
        raise EmptyInputError("the request body is empty; send JSON, multipart or float32 bytes")
    return body


@router.post(
    "/localize",
    response_model=Localization,
    responses=ERRORS,
    openapi_extra=body_doc(LocalizeRequest, IMAGE_FORM),
    summary="Localize one descriptor or image",
)
async def localize(request: Request) -> Response:
    """JSON ``{"map", "descriptor" | "descriptor_b64" | "image_b64"}`` or a multipart form
    with a ``map`` field and an ``image`` file."""
    svc = _service(request)
    ctype = request.headers.get("content-type", "")
    if ctype.startswith("multipart/form-data"):
        name, images, given = await _form(request, VEHICLE_FIELDS)
        if len(images) != 1:
            raise InvalidInputError(f"send one image here ({len(images)} sent); use /v1/localize/batch")
        if given:  # validated as the JSON body's fields are
            who = VehicleOptions.model_validate(given)
            return _one(*await run_in_threadpool(_localize_vehicle, request, name, who, images))
        return _one(await run_in_threadpool(svc.localize_images, name, images))
    req = LocalizeRequest.model_validate_json(await _json_body(request))
    if any(getattr(req, f) is not None for f in VEHICLE_FIELDS):
        return _one(*await run_in_threadpool(_localize_vehicle, request, req.map, req, None))
    batcher = request.app.state.context.batcher
    if batcher is None or req.image_b64 is not None:
        return _one(await run_in_threadpool(_localize_one, svc, req))
    if req.descriptor_b64 is not None:
        raw = decode_float32(_b64(req.descriptor_b64, "descriptor_b64"), None, "descriptor_b64")
        return _one(await batcher.localize(req.map, raw))
    return _one(await batcher.localize(req.map, _descriptor_row(req)))


def _localize_vehicle(request: Request, name: str, req: LocalizeRequest | VehicleOptions,
                      images: list[tuple[str, bytes]] | None) -> tuple[LocalizeResult, str | None]:  # fmt: skip
    """One query of a named vehicle: adapted to its earlier queries sent with its key (or as
    sent, if asked), and the key; the query is ``images`` (a form's file) or the JSON body's."""
    ctx = request.app.state.context
    svc: LocalizationService = ctx.service
    start = time.perf_counter()
    loaded = svc.served(name)
    if images is not None or not isinstance(req, LocalizeRequest):
        kind = "image"
        Q = svc.query_images(loaded, images or [])
    elif req.image_b64 is not None:
        kind = "image"
        Q = svc.query_images(loaded, [("image_b64", _b64(req.image_b64, "image_b64"))])
    elif req.descriptor_b64 is not None:
        kind = "descriptor"
        Q = svc.query_bytes(loaded, _b64(req.descriptor_b64, "descriptor_b64"))
    else:
        kind = "descriptor"
        Q = check_descriptors(_descriptor_row(req), n_features=loaded.n_features, what="descriptor")
    Q = one_descriptor(Q, loaded, "a query")
    return answer_vehicle(svc, ctx.vehicles, loaded, Q, start, kind, req.vehicle_id,
                          req.adaptation, req.vehicle_key, req.reset, req.condition)  # fmt: skip


def _localize_one(svc: LocalizationService, req: LocalizeRequest) -> LocalizeResult:
    if req.image_b64 is not None:
        return svc.localize_images(req.map, [("image_b64", _b64(req.image_b64, "image_b64"))])
    if req.descriptor_b64 is not None:
        raw = decode_float32(_b64(req.descriptor_b64, "descriptor_b64"), None, "descriptor_b64")
        return svc.localize(req.map, raw)
    return svc.localize(req.map, _descriptor_row(req))


def _descriptor_row(req: LocalizeRequest) -> list[list[float]]:
    assert req.descriptor is not None
    if not req.descriptor:
        raise EmptyInputError("descriptor is an empty list")
    return [req.descriptor]  # one row: a wrong d is named as such


@router.post(
    "/localize/batch",
    response_model=BatchLocalization,
    responses=ERRORS,
    openapi_extra=body_doc(BatchLocalizeRequest, IMAGES_FORM,
                           binary="n·d little-endian float32; the map as ?map= (required), d as ?d="),
    summary="Localize many descriptors or images in one call",
)
async def localize_batch(
    request: Request,
    map_q: Annotated[MapParam, Query(alias="map", description="the map (binary bodies)")] = None,
    d_q: Annotated[DimParam, Query(alias="d", description="descriptor size (binary)")] = None,
    map_h: Annotated[MapParam, Header(alias="X-Gridplace-Map", description="or the map here")] = None,
    d_h: Annotated[DimParam, Header(alias="X-Gridplace-Dim", description="or d here")] = None,
    condition_q: Annotated[ConditionParam, Query(alias="condition", description=(
        "the condition the queries were taken in (binary bodies and forms; JSON: the "
        "'condition' field): " + CONDITION_DOC))] = None,  # fmt: skip
) -> Response:
    """JSON ``{"map", "descriptors" | "descriptors_b64" | "images_b64"}``, a multipart form
    (``map`` + ``images`` files), or an ``application/octet-stream`` body of float32."""
    svc = _service(request)
    ctype = request.headers.get("content-type", "")
    if ctype.startswith("application/octet-stream"):
        name = binary_map(map_q, map_h, "batches")
        body = await request.body()
        result = await run_in_threadpool(svc.localize_bytes, name, body, d_q or d_h, condition_q)
    elif ctype.startswith("multipart/form-data"):
        name, images, given = await _form(request, ("condition",))
        condition = given.get("condition", condition_q)
        result = await run_in_threadpool(svc.localize_images, name, images, condition)
    else:
        req = BatchLocalizeRequest.model_validate_json(await _json_body(request))
        result = await run_in_threadpool(_localize_many, svc, req)
    return _many(result)


def _localize_many(svc: LocalizationService, req: BatchLocalizeRequest) -> LocalizeResult:
    if req.images_b64 is not None:
        blobs = [(f"images_b64[{i}]", _b64(t, f"images_b64[{i}]")) for i, t in enumerate(req.images_b64)]
        return svc.localize_images(req.map, blobs, req.condition)
    if req.descriptors_b64 is not None:
        return svc.localize_bytes(req.map, _b64(req.descriptors_b64, "descriptors_b64"),
                                  condition=req.condition)  # fmt: skip
    assert req.descriptors is not None
    if not req.descriptors:
        raise EmptyInputError("descriptors is an empty list")
    if len({len(row) for row in req.descriptors}) != 1:
        raise InvalidInputError("descriptors rows have different lengths")
    return svc.localize(req.map, req.descriptors, condition=req.condition)

"""The REST API's bodies: the shared wire models (:mod:`service.wire`), their conversion from
service-layer results, and the parts of the OpenAPI schema FastAPI cannot derive itself
(multipart forms and binary bodies read by hand)."""

from __future__ import annotations

from typing import Annotated, Any

from pydantic import Field
from pydantic.json_schema import SkipJsonSchema

from service.core.localization import LocalizeResult
from service.wire import (
    MAP_NAME_PATTERN,
    AppendOptions,
    BatchLocalization,
    ErrorBody,
    Localization,
    TrainingOptions,
)
from service.wire.localize import CONDITION_DOC

# optional query/header parameters: absent, never null (a null would arrive as the text "null")
MapParam = Annotated[str, Field(pattern=MAP_NAME_PATTERN)] | SkipJsonSchema[None]
DimParam = Annotated[int, Field(ge=1)] | SkipJsonSchema[None]
ConditionParam = Annotated[str, Field(min_length=1, max_length=4096)] | SkipJsonSchema[None]
TextParam = Annotated[str, Field(min_length=1)] | SkipJsonSchema[None]

ERRORS: dict[int | str, dict[str, Any]] = {
    s: {"model": ErrorBody, "description": d} for s, d in (
        (400, "the data cannot be used (named in the message)"), (404, "unknown map"),
        (409, "the map's state forbids it (no active version…)"),
        (413, "the body exceeds a size limit"), (422, "the request does not match this schema"),
        (503, "not ready yet or a dependency is down; retry"),
    )
}  # fmt: skip
ADMIN_ERRORS: dict[int | str, dict[str, Any]] = {
    **ERRORS,
    401: {"model": ErrorBody, "description": "no or wrong bearer token"},
    403: {"model": ErrorBody, "description": "the admin API is disabled on this server"},
}


def localization(r: LocalizeResult) -> Localization:
    return Localization(map=r.map, version=r.version, index=int(r.index[0]),
                        chunk=int(r.chunk[0]), confidence=float(r.confidence[0]),
                        latency_ms=r.latency_ms)  # fmt: skip


def batch_localization(r: LocalizeResult) -> BatchLocalization:
    return BatchLocalization(map=r.map, version=r.version, n=len(r), index=r.index.tolist(),
                             chunk=r.chunk.tolist(), confidence=r.confidence.tolist(),
                             latency_ms=r.latency_ms)  # fmt: skip


# -- OpenAPI of bodies read by hand -----------------------------------------------------------
def component(model: type[Any]) -> dict[str, Any]:
    """``model``'s JSON schema with references into ``#/components/schemas``."""
    return model.model_json_schema(ref_template="#/components/schemas/{model}")  # type: ignore[no-any-return]


def inline_schema(model: type[Any]) -> dict[str, Any]:
    """``model``'s JSON schema with the models it nests written in place: a body declared in
    ``openapi_extra`` does not add its ``$defs`` to ``#/components/schemas``, so a reference
    there would not resolve (and fuzzers would skip the field)."""
    schema = model.model_json_schema(ref_template="#/$defs/{model}")
    defs = schema.pop("$defs", {})

    def resolve(node: Any) -> Any:
        if isinstance(node, dict):
            ref = node.get("$ref")
            if isinstance(ref, str) and ref.startswith("#/$defs/"):
                rest = {k: resolve(v) for k, v in node.items() if k != "$ref"}
                return {**resolve(defs[ref.removeprefix("#/$defs/")]), **rest}
            return {k: resolve(v) for k, v in node.items()}
        if isinstance(node, list):
            return [resolve(v) for v in node]
        return node

    return resolve(schema)  # type: ignore[no-any-return]


def _form_property(schema: dict[str, Any]) -> dict[str, Any]:
    """A form field's schema: form fields are never null (an absent field is the default)."""
    out = {k: v for k, v in schema.items() if k not in ("anyOf", "default")}
    variants = [v for v in schema.get("anyOf", []) if v.get("type") != "null"]
    if len(variants) == 1:
        out.update(variants[0])
    elif variants:
        out["anyOf"] = variants
    return out


def form_schema(model: type[Any], files: dict[str, dict[str, Any]],
                required: tuple[str, ...] = ()) -> dict[str, Any]:  # fmt: skip
    """A ``multipart/form-data`` schema: ``model``'s fields as text fields plus ``files``."""
    props = {k: _form_property(v) for k, v in component(model).get("properties", {}).items()}
    return {"type": "object", "properties": {**props, **files},
            "required": [*required, *files], "additionalProperties": False}  # fmt: skip


BINARY = {"type": "string", "format": "binary"}
MAP_FIELD = {"type": "string", "pattern": MAP_NAME_PATTERN, "description": "map (route) name"}
CONDITION_FIELD = {"type": "string", "minLength": 1, "maxLength": 4096, "description": CONDITION_DOC}
IMAGE_FORM = {"type": "object", "required": ["map", "image"], "properties": {
    "map": MAP_FIELD, "image": {**BINARY, "description": "an encoded image (PNG, JPEG…)"},
    "condition": CONDITION_FIELD}}  # fmt: skip
IMAGES_FORM = {"type": "object", "required": ["map", "images"], "properties": {
    "map": MAP_FIELD, "images": {"type": "array", "minItems": 1, "items": BINARY},
    "condition": CONDITION_FIELD}}  # fmt: skip
APPEND_FORM = form_schema(AppendOptions, {"file": {
    **BINARY, "description": ".npy/.npz descriptors of the version's width, or a .zip/.tar of "
    "images its extractor reads; repeat the field for several traversals"}})  # fmt: skip
APPEND_FORM["properties"]["places"] = {
    **BINARY, "description": "optional, once per 'file' in the same order: an integer .npy "
    "giving the place of every row (0…N−1; beyond N with extend)"}  # fmt: skip
ROUTE_FORM = form_schema(TrainingOptions, {"file": {
    **BINARY, "description": ".npy/.npz descriptors, or a .zip/.tar of images in route order; "
    "repeat the field for several traversals of the same places"}})  # fmt: skip
ROUTE_FORM["properties"]["places"] = {
    **BINARY, "description": "optional, once per 'file' in the same order: an integer .npy "
    "giving the place (0…N−1) of every row of that traversal"}  # fmt: skip


def body_doc(json_model: type[Any] | None, multipart: dict[str, Any] | None = None,
             binary: str | None = None) -> dict[str, Any]:  # fmt: skip
    """``openapi_extra`` declaring a request body read by hand, per content type."""
    content: dict[str, Any] = {}
    if json_model is not None:
        content["application/json"] = {"schema": inline_schema(json_model)}
    if multipart is not None:
        content["multipart/form-data"] = {"schema": multipart}
    if binary is not None:
        content["application/octet-stream"] = {"schema": {**BINARY, "description": binary}}
    return {"requestBody": {"required": True, "content": content}}

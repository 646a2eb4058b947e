"""The wire models state the server's own rules: their bounds equal the library's, and the
OpenAPI schema is built from them (one declaration per field)."""

from __future__ import annotations

from typing import Any

import pytest
from pydantic import BaseModel, ValidationError

from service.encoding import ModelParams
from service.imaging.config import CnnConfig, HogConfig, PatchNormConfig
from service.wire import LocalizeRequest, TrainingOptions
from service.wire.training import EXTRACTOR_FIELDS, UPLOAD_FIELDS

KEYS = ("minimum", "maximum", "exclusiveMinimum", "exclusiveMaximum", "enum", "const",
        "minItems", "maxItems")  # fmt: skip


def _constraints(model: type[BaseModel], field: str) -> dict[str, Any]:
    prop = model.model_json_schema()["properties"][field]
    variants = [v for v in prop.get("anyOf", [prop]) if v.get("type") != "null"]
    assert len(variants) == 1, (model, field, prop)
    v = variants[0]
    out = {k: v[k] for k in KEYS if k in v}
    if "items" in v:
        out["items"] = {k: v["items"][k] for k in KEYS if k in v["items"]}
    return out


SHARED = sorted(set(TrainingOptions.model_fields) & set(ModelParams.model_fields))


def test_every_training_field_of_the_upload_is_a_model_parameter() -> None:
    training = set(TrainingOptions.model_fields) - {"extractor", *EXTRACTOR_FIELDS, *UPLOAD_FIELDS}
    assert training == set(SHARED)


@pytest.mark.parametrize("field", SHARED)
def test_training_bounds_equal_the_libraries(field: str) -> None:
    assert _constraints(TrainingOptions, field) == _constraints(ModelParams, field)


@pytest.mark.parametrize(("field", "value"), [
    ("gamma", float("inf")), ("gamma", float("nan")), ("C", float("inf")), ("C", 1e300),
    ("random_state", -5), ("random_state", 2**32), ("random_state", 2**32 - 1),
    ("periods", [2] * 65), ("periods", [2] * 64), ("periods", [2**31]), ("periods", []),
    ("rho", 1.0), ("rho", 0.0), ("top_chunks", 100_001),
])  # fmt: skip
def test_edge_values_are_accepted_by_both_or_neither(field: str, value: Any) -> None:
    def ok(model: type[BaseModel]) -> bool:
        try:
            model(**{field: value})
        except ValidationError:
            return False
        return True

    assert ok(TrainingOptions) == ok(ModelParams), (field, value)


@pytest.mark.parametrize("field", [f for f in EXTRACTOR_FIELDS if f != "preset"])
def test_extractor_bounds_span_every_extractor(field: str) -> None:
    configs = [c for c in (PatchNormConfig, HogConfig, CnnConfig) if field in c.model_fields]
    each = [_constraints(c, field) for c in configs]
    wire = _constraints(TrainingOptions, field)
    assert wire["minimum"] == min(c["minimum"] for c in each)
    assert wire["maximum"] == max(c["maximum"] for c in each)


def test_the_openapi_schema_is_built_from_the_wire_models() -> None:
    from service.api import schemas
    from service.api.app import create_app
    from service.settings import Settings

    assert not [v for v in vars(schemas).values()
                if isinstance(v, type) and issubclass(v, BaseModel) and v.__module__ == schemas.__name__]  # fmt: skip
    spec = create_app(Settings(insecure_dev=True)).openapi()
    components = spec["components"]["schemas"]
    assert {"Job", "Version", "MapSummary", "MapDetail", "Localization", "BatchLocalization",
            "ErrorBody"} <= set(components)  # fmt: skip
    body = spec["paths"]["/v1/localize"]["post"]["requestBody"]["content"]
    assert body["application/json"]["schema"]["oneOf"] == LocalizeRequest.model_json_schema()["oneOf"]
    form = spec["paths"]["/v1/maps/{name}/routes"]["post"]["requestBody"]["content"]
    props = form["multipart/form-data"]["schema"]["properties"]
    assert set(props) == {*TrainingOptions.model_fields, "file", "places"}
    assert props["rho"] == {"type": "number", "exclusiveMinimum": 0.0, "maximum": 1.0,
                            "title": "Rho", "description": "fraction of columns per encoder"}  # fmt: skip
    version = spec["paths"]["/v1/maps/{name}/versions/{version}"]["get"]["parameters"][1]
    assert version["schema"]["minimum"] == 1 and version["schema"]["maximum"] == 2**63 - 1

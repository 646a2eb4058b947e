"""Where REST and gRPC read the same field, a real ``gridplace serve`` reads it the same way:
an empty ``vehicle_id`` is refused by both; and JSON ``true`` is not a number (pydantic's lax
mode read it as 1.0 in filter options and descriptor rows)."""

from __future__ import annotations

import httpx
import numpy as np
import pytest
from grpc_helpers import Served
from test_grpc_stream import f32, run

from service.grpc.gen import localization_pb2 as pb


def test_an_empty_vehicle_id_is_refused_by_rest_and_by_grpc(served: Served) -> None:
    row = served.query[3].astype(np.float32)
    r = httpx.post(f"{served.srv.url}/v1/localize", timeout=30,
                   json={"map": "route", "descriptor": row.tolist(), "vehicle_id": ""})  # fmt: skip
    assert r.status_code == 422 and "vehicle_id" in r.text
    (got,) = run(served, [
        pb.StreamRequest(vehicle_id="", sequence=1, map="route", descriptor=f32(row)),
        pb.StreamRequest(vehicle_id="car", sequence=2, map="route", descriptor=f32(row)),
        pb.StreamRequest(vehicle_id="x" * 129, sequence=3, map="route", descriptor=f32(row)),
    ])  # fmt: skip
    assert got[0].error.status == "INVALID_ARGUMENT" and "vehicle_id" in got[0].error.message
    assert not got[1].HasField("error")
    assert got[2].error.status == "INVALID_ARGUMENT"


@pytest.mark.parametrize("option, number", [("min_speed", 1), ("speed_step", 1),
                                            ("relocalization", 0.5), ("emission_scale", 1),
                                            ("confidence_radius", 1)])  # fmt: skip
def test_json_true_is_not_a_filter_number(served: Served, option: str, number: float) -> None:
    rows = served.query[:5].tolist()
    url = f"{served.srv.url}/v1/localize/sequence"
    r = httpx.post(url, timeout=30, json={"map": "route", "descriptors": rows,
                                          "filter": {option: True}})  # fmt: skip
    assert r.status_code == 422, r.text
    assert f"filter.{option}" in r.json()["message"] and "boolean" in r.json()["message"]
    ok = httpx.post(url, timeout=30, json={"map": "route", "descriptors": rows,
                                           "filter": {option: number}})  # fmt: skip
    assert ok.status_code == 200, ok.text  # a JSON number (an integer too) is still one


@pytest.mark.parametrize("path, body", [
    ("/v1/localize", lambda row: {"descriptor": [True, *row[1:]]}),
    ("/v1/localize/batch", lambda row: {"descriptors": [row, [*row[:-1], True]]}),
    ("/v1/localize/sequence", lambda row: {"descriptors": [row, [False, *row[1:]]]}),
    ("/v1/localize/batch", lambda row: {"descriptors": [[str(v) for v in row]]}),
])  # fmt: skip
def test_json_booleans_and_strings_are_not_descriptor_values(served: Served, path: str, body) -> None:  # type: ignore[no-untyped-def]
    row = [float(v) for v in served.query[4]]
    r = httpx.post(f"{served.srv.url}{path}", timeout=30, json={"map": "route", **body(row)})
    assert r.status_code == 422, r.text
    whole = {"descriptor": [round(v) for v in row]} if path == "/v1/localize" else \
        {"descriptors": [[round(v) for v in row]] * 2}
    assert httpx.post(f"{served.srv.url}{path}", timeout=30,
                      json={"map": "route", **whole}).status_code == 200  # integers are numbers

"""The grpcurl request body of ``gridplace demo`` follows the shipped proto's field types."""

from __future__ import annotations

import base64
from pathlib import Path

import numpy as np

from service.cli.demo_examples import localize_body, request_fields

PROTO = """syntax = "proto3";
package gridplace.v1;
message LocalizeRequest {
  string map = 1;
  // one query
  repeated float descriptor = 2;
  bytes image = 3;
}
message Other { int32 x = 1; }
"""


def test_fields_are_read_from_the_proto(tmp_path: Path) -> None:
    (tmp_path / "gridplace" / "v1").mkdir(parents=True)
    (tmp_path / "gridplace" / "v1" / "localization.proto").write_text(PROTO)
    fields = request_fields(tmp_path)
    assert fields == {"map": "string", "descriptor": "repeated float", "image": "bytes"}
    body = localize_body(np.array([0.5, -1.0]), fields)
    assert body == {"map": "demo", "descriptor": [0.5, -1.0]}
    assert request_fields(tmp_path / "absent") == {}


def test_a_bytes_descriptor_is_base64_float32() -> None:
    body = localize_body(np.array([1.0, 2.0]), {"map": "string", "descriptor_f32": "bytes"})
    raw = base64.b64decode(str(body["descriptor_f32"]))
    assert np.frombuffer(raw, "<f4").tolist() == [1.0, 2.0] and body["map"] == "demo"
    assert localize_body(np.ones(2), {}) == {"map": "demo", "descriptor": [1.0, 1.0]}

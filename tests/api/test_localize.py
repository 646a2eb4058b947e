"""POST /v1/localize and /v1/localize/batch in-process: every input form and bad input."""

from __future__ import annotations

import base64

import pytest
from api_helpers import expected_index, png_bytes
from fastapi.testclient import TestClient


def test_single_json_descriptor_finds_its_frame(client: TestClient, trained: str, route, registry) -> None:
    ref, _ = route
    r = client.post("/v1/localize", json={"map": trained, "descriptor": ref[17].tolist()})
    assert r.status_code == 200, r.text
    body = r.json()
    assert body["map"] == trained and body["version"] == 1
    assert [body["index"]] == expected_index(registry, trained, 1, ref[17]) and body["chunk"] == 0
    assert 0.0 <= body["confidence"] <= 1.0 and body["latency_ms"] > 0


def test_b64_descriptor_equals_json(client: TestClient, trained: str, route) -> None:
    q = route[1][40]
    b64 = base64.b64encode(q.astype("<f4").tobytes()).decode()
    a = client.post("/v1/localize", json={"map": trained, "descriptor_b64": b64}).json()
    b = client.post("/v1/localize", json={"map": trained, "descriptor": q.tolist()}).json()
    assert a["index"] == b["index"] and a["confidence"] == pytest.approx(b["confidence"])


def test_batch_json_binary_and_b64_agree(client: TestClient, trained: str, route, registry) -> None:
    Q = route[1][:50]
    js = client.post("/v1/localize/batch", json={"map": trained, "descriptors": Q.tolist()})
    raw = Q.astype("<f4").tobytes()
    bn = client.post(f"/v1/localize/batch?map={trained}&d={Q.shape[1]}", content=raw,
                     headers={"Content-Type": "application/octet-stream"})  # fmt: skip
    hd = client.post("/v1/localize/batch", content=raw,
                     headers={"Content-Type": "application/octet-stream", "X-Gridplace-Map": trained})  # fmt: skip
    b64 = client.post("/v1/localize/batch",
                      json={"map": trained, "descriptors_b64": base64.b64encode(raw).decode()})  # fmt: skip
    for r in (js, bn, hd, b64):
        assert r.status_code == 200, r.text
        assert r.json()["n"] == 50
    assert js.json()["index"] == bn.json()["index"] == hd.json()["index"] == b64.json()["index"]
    assert js.json()["index"] == expected_index(registry, trained, 1, Q)


@pytest.mark.parametrize(
    ("payload", "status", "code"),
    [
        ({"map": "synthetic", "descriptor": [0.0] * 31}, 400, "dimension_mismatch"),
        # what the schema says (minItems, base64 of whole float32 values) is a 422
        ({"map": "synthetic", "descriptor": []}, 422, "validation_error"),
        ({"map": "synthetic", "descriptor_b64": "***not base64***"}, 422, "validation_error"),
        ({"map": "synthetic", "descriptor_b64": base64.b64encode(b"abc").decode()}, 422, "validation_error"),
        ({"map": "synthetic", "image_b64": base64.b64encode(b"not an image").decode()}, 409, "conflict"),
        ({"map": "synthetic"}, 422, "validation_error"),
        ({"descriptor": [1.0]}, 422, "validation_error"),
        ({"map": "synthetic", "descriptor": ["a"]}, 422, "validation_error"),
        ({"map": "nowhere", "descriptor": [0.0] * 32}, 404, "not_found"),
    ],
)
def test_bad_single_requests(client: TestClient, trained: str, payload, status: int, code: str) -> None:
    r = client.post("/v1/localize", json=payload)
    assert r.status_code == status, r.text
    assert r.json()["error"] == code and r.json()["message"]


def test_nan_and_inf_are_400_naming_the_position(client: TestClient, trained: str) -> None:
    for token in ("NaN", "Infinity", "-Infinity"):
        body = '{"map": "synthetic", "descriptor": [%s%s]}' % (token, ", 0.0" * 31)
        r = client.post("/v1/localize", content=body, headers={"Content-Type": "application/json"})
        assert r.status_code == 400 and r.json()["error"] == "non_finite_input"
        assert "column 0" in r.json()["message"]


def test_empty_and_malformed_bodies(client: TestClient, trained: str) -> None:
    r = client.post("/v1/localize", content=b"", headers={"Content-Type": "application/json"})
    assert r.status_code == 400 and r.json()["error"] == "empty_input"
    r = client.post("/v1/localize", content=b"{not json", headers={"Content-Type": "application/json"})
    assert r.status_code == 400 and r.json()["error"] == "validation_error"
    r = client.post("/v1/localize/batch?map=synthetic", content=b"",
                    headers={"Content-Type": "application/octet-stream"})  # fmt: skip
    assert r.status_code == 400 and r.json()["error"] == "empty_input"
    r = client.post("/v1/localize/batch?map=synthetic", content=b"\x00" * 4 * 33,
                    headers={"Content-Type": "application/octet-stream"})  # fmt: skip
    assert r.status_code == 400 and r.json()["error"] == "dimension_mismatch"
    r = client.post("/v1/localize/batch?map=synthetic&d=16", content=b"\x00" * 64,
                    headers={"Content-Type": "application/octet-stream"})  # fmt: skip
    assert r.status_code == 400 and r.json()["error"] == "dimension_mismatch"
    r = client.post("/v1/localize/batch", content=b"\x00" * 128,
                    headers={"Content-Type": "application/octet-stream"})  # fmt: skip
    assert r.status_code == 400 and "map" in r.json()["message"]
    r = client.post("/v1/localize/batch", json={"map": "synthetic", "descriptors": [[1.0] * 32, [1.0]]})
    assert r.status_code == 400


def test_no_active_version_is_409(client: TestClient, trained: str, auth) -> None:
    d = client.post(f"/v1/maps/{trained}/deactivate", headers=auth)
    assert d.status_code == 200 and d.json()["active_version"] is None
    assert client.post("/v1/maps/nowhere/deactivate", headers=auth).status_code == 404
    r = client.post("/v1/localize", json={"map": trained, "descriptor": [0.0] * 32})
    assert r.status_code == 409 and r.json()["error"] == "conflict"


def test_images_need_an_extractor_and_are_decoded(client: TestClient, auth, registry) -> None:
    from api_helpers import upload_image_map

    from service.imaging import make_extractor
    from service.imaging.decode import decode_image

    upload_image_map(client, auth)
    ext = make_extractor(registry.get_version("imgs", 1).extractor)
    assert ext.config.width == 32 and ext.config.patch == 8

    def want(*ids: int) -> list[int]:
        X = ext.extract([decode_image(png_bytes(i)) for i in ids])
        return expected_index(registry, "imgs", 1, X)

    one = client.post("/v1/localize", json={"map": "imgs", "image_b64": base64.b64encode(png_bytes(7)).decode()})
    assert one.status_code == 200 and [one.json()["index"]] == want(7)
    form = client.post("/v1/localize", data={"map": "imgs"}, files={"image": ("q.png", png_bytes(9))})
    assert form.status_code == 200 and [form.json()["index"]] == want(9)
    many = client.post("/v1/localize/batch", data={"map": "imgs"},
                       files=[("images", (f"{i}.png", png_bytes(i))) for i in (3, 4)])  # fmt: skip
    assert many.status_code == 200 and many.json()["index"] == want(3, 4)
    bad = client.post("/v1/localize", data={"map": "imgs"}, files={"image": ("q.png", b"GIF89 nope")})
    assert bad.status_code == 400 and "not a decodable image" in bad.json()["message"]

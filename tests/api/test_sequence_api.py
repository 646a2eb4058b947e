"""POST /v1/localize/sequence in-process: image drives (form and base64), the documented
filter parameters, and one map version answering a whole drive (SYNTHETIC data)."""

from __future__ import annotations

import base64

import numpy as np
from api_helpers import png_bytes, upload_image_map
from fastapi.testclient import TestClient

from service.encoding.sequence import SequenceConfig, filter_sequence


def test_an_image_drive_as_a_form_or_base64_is_the_library_filter(
    client: TestClient, auth, registry
) -> None:
    from service.imaging import make_extractor
    from service.imaging.decode import decode_image

    upload_image_map(client, auth, n_frames=40)
    drive = list(range(5, 30))
    ext = make_extractor(registry.get_version("imgs", 1).extractor)
    X = ext.extract([decode_image(png_bytes(i)) for i in drive])
    model = registry.load_model("imgs", 1)
    want = filter_sequence(model.frame_log_scores(X), SequenceConfig(max_speed=3.0)).index.tolist()

    form = client.post(
        "/v1/localize/sequence?max_speed=3",
        data={"map": "imgs"},
        files=[("images", (f"{i}.png", png_bytes(i))) for i in drive],
    )
    b64 = client.post(
        "/v1/localize/sequence",
        json={
            "map": "imgs",
            "filter": {"max_speed": 3.0},
            "images_b64": [base64.b64encode(png_bytes(i)).decode() for i in drive],
        },
    )
    for res in (form, b64):
        assert res.status_code == 200, res.text
        body = res.json()
        assert body["n"] == len(drive) and body["index"] == want and body["version"] == 1
        assert body["raw_index"] == model.localize(X).index.tolist()
        assert all(c == 0 for c in body["chunk"]) and body["filter"]["max_speed"] == 3.0
    bad = client.post(
        "/v1/localize/sequence",
        data={"map": "imgs"},
        files=[("images", ("a.png", png_bytes(1))), ("images", ("b.png", b"GIF89 nope"))],
    )
    assert bad.status_code == 400 and "b.png" in bad.json()["message"]


def test_a_descriptor_map_refuses_images_and_empty_drives(client: TestClient, trained: str) -> None:
    r = client.post(
        "/v1/localize/sequence",
        json={"map": trained, "images_b64": [base64.b64encode(png_bytes(1)).decode()]},
    )
    assert r.status_code == 409 and r.json()["error"] == "conflict"
    r = client.post(
        f"/v1/localize/sequence?map={trained}",
        content=b"",
        headers={"Content-Type": "application/octet-stream"},
    )
    assert r.status_code == 400 and r.json()["error"] == "empty_input"
    r = client.post(
        "/v1/localize/sequence", json={"map": trained, "descriptors": [[0.0] * 32, [0.0] * 31]}
    )
    assert r.status_code == 400 and "different lengths" in r.json()["message"]


def test_a_chunked_map_names_the_chunk_of_each_filtered_estimate(
    client: TestClient, auth, route
) -> None:
    from api_helpers import npy_bytes

    r = client.post(
        "/v1/maps/chunky/routes",
        headers=auth,
        files={"file": ("route.npy", npy_bytes(route[0]))},
        data={"trainer": "ridge", "n_chunks": "3"},
    )
    assert r.status_code == 202, r.text
    client.app.state.context.store.refresh()
    body = client.post(
        "/v1/localize/sequence", json={"map": "chunky", "descriptors": route[1].tolist()}
    ).json()
    bounds = np.asarray(client.app.state.context.store.get("chunky").model.chunk_bounds_)
    for index, chunk in zip(body["index"], body["chunk"], strict=True):
        assert bounds[chunk] <= index < bounds[chunk + 1]
    truth = np.arange(len(body["index"]))
    assert np.mean(np.abs(np.array(body["index"]) - truth) <= 2) > 0.8


def test_openapi_documents_the_endpoint_and_every_filter_parameter(client: TestClient) -> None:
    op = client.get("/openapi.json").json()["paths"]["/v1/localize/sequence"]["post"]
    params = {p["name"]: p for p in op["parameters"]}
    for name, field in SequenceConfig.model_fields.items():
        assert name in params and str(field.default) in params[name]["description"]
    assert params["emission_scale"]["schema"]["exclusiveMinimum"] == 0.0
    assert set(op["requestBody"]["content"]) == {
        "application/json",
        "multipart/form-data",
        "application/octet-stream",
    }


def test_a_drive_beyond_the_work_budget_is_a_413_naming_it(
    client: TestClient, trained: str, route, settings
) -> None:
    # N = 120, the default filter's S states (+ 8: the frames' own scores): 50 frames a drive
    S = SequenceConfig().n_states
    settings.max_request_work = 120 * 50 * (8 + S) / 1e6
    ok = client.post(
        "/v1/localize/sequence", json={"map": trained, "descriptors": route[1][:50].tolist()}
    )
    assert ok.status_code == 200, ok.text
    r = client.post(
        "/v1/localize/sequence", json={"map": trained, "descriptors": route[1][:51].tolist()}
    )
    budget = 120 * 50 * (8 + S)
    assert r.status_code == 413 and r.json()["details"] == {"work": 51 * 120 * (8 + S), "budget": budget}
    assert "GRIDPLACE_MAX_REQUEST_WORK" in r.json()["message"]
    assert f"51 frames × 120 map frames × (8 + {S} states)" in r.json()["message"]
    grid = {"min_speed": 0, "max_speed": 3.5, "speed_step": 0.25}
    wide_s = SequenceConfig(**grid).n_states
    fits = budget // (120 * (8 + wide_s))
    wide = client.post("/v1/localize/sequence", json={  # within the budget with the wider grid
        "map": trained, "descriptors": route[1][:fits].tolist(), "filter": grid})  # fmt: skip
    assert wide.status_code == 200, wide.text
    wider = client.post("/v1/localize/sequence", json={  # one frame more is not
        "map": trained, "descriptors": route[1][: fits + 1].tolist(), "filter": grid})  # fmt: skip
    assert wider.status_code == 413 and f"(8 + {wide_s} states)" in wider.json()["message"]


def test_the_wire_options_carry_the_filters_bounds() -> None:
    """Every filter parameter is a wire option with the same type and static bounds, so the
    OpenAPI schema and the client refuse what the server refuses."""
    from service.wire import SequenceFilterOptions

    lib = SequenceConfig.model_json_schema()["properties"]
    wire = SequenceFilterOptions.model_json_schema()["properties"]
    assert set(lib) == set(wire)
    keep = ("type", "enum", "minimum", "maximum", "exclusiveMinimum", "exclusiveMaximum")
    for name, prop in wire.items():
        variant = next(v for v in prop["anyOf"] if v.get("type") != "null")
        want = {k: v for k, v in lib[name].items() if k in keep}
        assert {k: v for k, v in variant.items() if k in keep} == want, name
        assert prop["description"] == lib[name]["description"], name


def test_drives_are_adapted_unless_the_request_says_not(client: TestClient, trained: str,
                                                        registry, route) -> None:  # fmt: skip
    from service.encoding import PhaseEncoder
    from service.encoding.adaptation import adapt_drive

    Q = route[1][:80].astype(np.float32)
    model = client.app.state.context.store.get(trained).model
    adapted = model.localize(adapt_drive(model, Q.astype(np.float64))).index.tolist()
    plain = model.localize(Q).index.tolist()
    url = f"/v1/localize/sequence?map={trained}&d={Q.shape[1]}"
    binary = {"content": Q.tobytes(), "headers": {"Content-Type": "application/octet-stream"}}
    on = client.post(url, **binary).json()
    off = client.post(url + "&adaptation=false", **binary).json()
    assert on["adapted"] and on["raw_index"] == adapted
    assert not off["adapted"] and off["raw_index"] == plain
    body = {"map": trained, "descriptors": Q.tolist()}
    assert client.post("/v1/localize/sequence", json={**body, "adaptation": False}).json()["raw_index"] == plain
    both = client.post("/v1/localize/sequence?adaptation=true", json={**body, "adaptation": False})
    assert both.status_code == 400 and "not both" in both.json()["message"]
    assert client.post(url + "&adaptation=maybe", **binary).status_code == 422
    # a map trained without normalisation keeps no statistics: asked for, adaptation is a 400
    bare_model = PhaseEncoder(n_patterns=2, trainer="ridge", normalize=False).fit(route[0])
    registry.publish("bare", bare_model, params={}, extractor=None, metrics={}, job_id=None)
    client.app.state.context.store.refresh()
    bare = {"map": "bare", "descriptors": Q.tolist()}
    assert client.post("/v1/localize/sequence", json=bare).json()["adapted"] is False
    refused = client.post("/v1/localize/sequence", json={**bare, "adaptation": True})
    assert refused.status_code == 400 and "route statistics" in refused.json()["message"]

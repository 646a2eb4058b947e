"""``POST /v1/localize`` with a ``vehicle_id``: each vehicle's queries adapted to its own
earlier ones, between requests (in-process app, SYNTHETIC route), and the adapters' LRU."""

from __future__ import annotations

import base64

import numpy as np
from api_helpers import png_bytes, upload_image_map
from fastapi.testclient import TestClient

from service.core.model_store import LoadedModel
from service.core.vehicle_adapters import VehicleAdapters
from service.encoding import ModelParams, build_model
from service.encoding.adaptation import adapt_drive
from service.encoding.synthetic import smooth_route


def _post(client: TestClient, body: dict) -> dict:
    r = client.post("/v1/localize", json=body)
    assert r.status_code == 200, r.text
    return r.json()


def test_a_vehicle_is_adapted_to_its_own_earlier_queries(client: TestClient, trained: str, route) -> None:
    Q = route[1][:60].astype(np.float32)
    model = client.app.state.context.store.get(trained).model
    drive_a = model.localize(adapt_drive(model, Q[::2].astype(np.float64))).index.tolist()
    drive_b = model.localize(adapt_drive(model, Q[1::2][::-1].astype(np.float64))).index.tolist()
    got_a, got_b = [], []
    for i in range(30):  # two vehicles interleaved, b driving backwards; b sends base64
        a = _post(client, {"map": trained, "descriptor": Q[2 * i].tolist(), "vehicle_id": "a"})
        b64 = base64.b64encode(Q[1::2][::-1][i].tobytes()).decode()
        b = _post(client, {"map": trained, "descriptor_b64": b64, "vehicle_id": "b"})
        assert a["adapted"] and b["adapted"]
        got_a.append(a["index"])
        got_b.append(b["index"])
    assert got_a == drive_a and got_b == drive_b
    # no vehicle, or a vehicle that opts out: answered as sent, its statistics untouched
    plain = int(model.localize(Q[5:6]).index[0])
    anon = _post(client, {"map": trained, "descriptor": Q[5].tolist()})
    assert not anon["adapted"] and anon["index"] == plain
    off = _post(client, {"map": trained, "descriptor": Q[5].tolist(), "vehicle_id": "a",
                         "adaptation": False})  # fmt: skip
    assert not off["adapted"] and off["index"] == plain
    nxt = _post(client, {"map": trained, "descriptor": Q[0].tolist(), "vehicle_id": "a"})
    longer = model.localize(adapt_drive(model, np.vstack([Q[::2], Q[:1]]).astype(np.float64))).index
    assert nxt["index"] == int(longer[-1])


def test_bad_vehicle_requests_are_4xx_naming_the_field(client: TestClient, trained: str) -> None:
    row = [0.0] * 32
    r = client.post("/v1/localize", json={"map": trained, "descriptor": row, "adaptation": True})
    assert r.status_code == 400 and "vehicle_id" in r.json()["message"]
    r = client.post("/v1/localize", json={"map": trained, "descriptor": row, "vehicle_id": "x" * 200})
    assert r.status_code == 422 and "vehicle_id" in r.text
    r = client.post("/v1/localize", json={"map": trained, "descriptor": row[:5], "vehicle_id": "v"})
    assert r.status_code == 400 and r.json()["error"] == "dimension_mismatch"
    r = client.post("/v1/localize", data={"map": trained, "vehicle_id": "v", "adaptation": "maybe"},
                    files={"image": ("a.png", png_bytes(1))})  # fmt: skip
    assert r.status_code == 422 and "adaptation" in r.text


def test_an_image_vehicle_gets_the_same_adapted_answers(client: TestClient, auth, registry) -> None:
    from service.imaging import make_extractor
    from service.imaging.decode import decode_image

    upload_image_map(client, auth)
    drive = [3, 9, 4, 20, 7]
    ext = make_extractor(registry.get_version("imgs", 1).extractor)
    model = registry.load_model("imgs", 1)
    X = ext.extract([decode_image(png_bytes(i)) for i in drive])
    want = model.localize(adapt_drive(model, X)).index.tolist()
    got = []
    for i in drive:
        r = client.post("/v1/localize", data={"map": "imgs", "vehicle_id": "cam"},
                        files={"image": (f"{i}.png", png_bytes(i))})  # fmt: skip
        assert r.status_code == 200 and r.json()["adapted"], r.text
        got.append(r.json()["index"])
    assert got == want


def _loaded(version: int, model: object) -> LoadedModel:
    return LoadedModel(map="m", version=version, model=model, info=None, extractor_config=None)  # type: ignore[arg-type]


def test_adapters_restart_with_the_version_and_forget_the_least_recent() -> None:
    route = smooth_route(80, 8, seed=5)  # SYNTHETIC
    model = build_model(ModelParams()).fit(route.reference)
    v1, v2 = _loaded(1, model), _loaded(2, model)
    adapters = VehicleAdapters(max_vehicles=2)
    Q = route.query
    a = np.vstack([adapters.adapt(v1, "a", Q[i : i + 1]) for i in range(10)])
    assert np.array_equal(a, adapt_drive(model, Q[:10]))
    restarted = adapters.adapt(v2, "a", Q[10:11])  # a new version: a fresh drive
    assert np.allclose(restarted, Q[10:11], atol=1e-5)
    adapters.adapt(v1, "b", Q[:1])
    adapters.adapt(v1, "c", Q[:1])
    assert len(adapters) == 2 and adapters.nbytes == 2 * 24 * 8

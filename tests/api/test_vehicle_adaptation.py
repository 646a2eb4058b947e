"""``POST /v1/localize`` with a ``vehicle_id``: each vehicle's queries adapted to its own
earlier ones, between requests (in-process app, SYNTHETIC route), and the adapters' LRU."""

from __future__ import annotations

import base64

import numpy as np
from api_helpers import png_bytes, upload_image_map
from fastapi.testclient import TestClient

from service.core.model_store import LoadedModel
from service.core.vehicle_adapters import VehicleAdapters
from service.core.vehicle_state import ENTRY_OVERHEAD_BYTES
from service.encoding import ModelParams, build_model
from service.encoding.adaptation import ADAPTER_OVERHEAD_BYTES, adapt_drive
from service.encoding.synthetic import smooth_route


def _post(client: TestClient, body: dict) -> dict:
    r = client.post("/v1/localize", json=body)
    assert r.status_code == 200, r.text
    return r.json()


class _Vehicle:
    """A vehicle sending its queries one request at a time, with the key its first answer
    carried."""

    def __init__(self, client: TestClient, map_name: str, vehicle_id: str, key: str | None = None) -> None:
        self.client, self.map, self.id, self.key = client, map_name, vehicle_id, key

    def send(self, row: np.ndarray, **extra: object) -> dict:
        body = {"map": self.map, "descriptor": np.asarray(row, np.float32).tolist(), "vehicle_id": self.id}
        if self.key is not None:
            body["vehicle_key"] = self.key
        got = _post(self.client, {**body, **extra})
        if got.get("vehicle_key"):
            self.key = got["vehicle_key"]
        return got


def test_a_vehicle_is_adapted_to_its_own_earlier_queries(client: TestClient, trained: str, route) -> None:
    Q = route[1][:60].astype(np.float32)
    model = client.app.state.context.store.get(trained).model
    drive_a = model.localize(adapt_drive(model, Q[::2].astype(np.float64))).index.tolist()
    drive_b = model.localize(adapt_drive(model, Q[1::2][::-1].astype(np.float64))).index.tolist()
    a, got_a, got_b = _Vehicle(client, trained, "a"), [], []
    b_key = None
    for i in range(30):  # two vehicles interleaved, b driving backwards; b sends base64
        ans_a = a.send(Q[2 * i])
        b64 = base64.b64encode(Q[1::2][::-1][i].tobytes()).decode()
        body = {"map": trained, "descriptor_b64": b64, "vehicle_id": "b"}
        ans_b = _post(client, body if b_key is None else {**body, "vehicle_key": b_key})
        assert ans_a["adapted"] and ans_b["adapted"]
        assert ans_a["vehicle_key"] == a.key and (b_key is None or ans_b["vehicle_key"] == b_key)
        b_key = ans_b["vehicle_key"]
        got_a.append(ans_a["index"])
        got_b.append(ans_b["index"])
    assert got_a == drive_a and got_b == drive_b
    assert len(a.key) >= 22 and a.key != b_key
    # no vehicle, or a vehicle that opts out: answered as sent, its statistics untouched
    plain = int(model.localize(Q[5:6]).index[0])
    anon = _post(client, {"map": trained, "descriptor": Q[5].tolist()})
    assert not anon["adapted"] and anon["index"] == plain and "vehicle_key" not in anon
    off = a.send(Q[5], adaptation=False)
    assert not off["adapted"] and off["index"] == plain
    nxt = a.send(Q[0])
    longer = model.localize(adapt_drive(model, np.vstack([Q[::2], Q[:1]]).astype(np.float64))).index
    assert nxt["index"] == int(longer[-1])


def test_only_the_keys_holder_reaches_a_vehicles_statistics(client: TestClient, trained: str,
                                                             route) -> None:  # fmt: skip
    """Another caller using the same vehicle_id, without the key or with a wrong one, drives
    a drive of its own; the vehicle's answers are those of its drive alone. With its key the
    vehicle may reset its statistics, and a key of its own choosing works as an issued one."""
    Q = route[1][:40].astype(np.float32)
    model = client.app.state.context.store.get(trained).model
    want = model.localize(adapt_drive(model, Q.astype(np.float64))).index.tolist()
    car = _Vehicle(client, trained, "shared-id")
    got = [car.send(q)["index"] for q in Q[:20]]
    rng = np.random.default_rng(0)
    for forged in (None, "x" * 32, car.key[:-1] + ("A" if car.key[-1] != "A" else "B")):
        intruder = _Vehicle(client, trained, "shared-id", forged)
        intruder.send(np.full(Q.shape[1], 1e6))  # a wild frame, then another drive
        for _ in range(10):
            intruder.send(rng.normal(size=Q.shape[1]) * 3 + 5)
        assert intruder.key != car.key
        r = client.post("/v1/localize", json={"map": trained, "descriptor": Q[0].tolist(),
                                              "vehicle_id": "shared-id", "reset": True,
                                              **({"vehicle_key": forged} if forged else {})})  # fmt: skip
        assert r.status_code == 200 and r.json()["vehicle_key"] != car.key
    got += [car.send(q)["index"] for q in Q[20:]]
    assert got == want
    restarted = car.send(Q[7], reset=True)  # the first frame of a new drive: as sent
    assert restarted["index"] == int(model.localize(Q[7:8]).index[0])
    own = _Vehicle(client, trained, "provisioned", key="my-own-key_0123456789abcdef")
    assert [own.send(q)["index"] for q in Q] == want and own.key == "my-own-key_0123456789abcdef"


def test_bad_vehicle_requests_are_4xx_naming_the_field(client: TestClient, trained: str) -> None:
    row = [0.0] * 32
    r = client.post("/v1/localize", json={"map": trained, "descriptor": row, "adaptation": True})
    assert r.status_code == 400 and "vehicle_id" in r.json()["message"]
    for extra in ({"vehicle_key": "k" * 30}, {"reset": True}):
        r = client.post("/v1/localize", json={"map": trained, "descriptor": row, **extra})
        assert r.status_code == 400 and "needs a vehicle_id" in r.json()["message"], r.text
    for bad in ("short", "k" * 129, "has space in it 0123456789", "ü" * 30):
        r = client.post("/v1/localize", json={"map": trained, "descriptor": row, "vehicle_id": "v",
                                              "vehicle_key": bad})  # fmt: skip
        assert r.status_code == 422 and "vehicle_key" in r.text
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
    got, key = [], {}
    for i in drive:
        r = client.post("/v1/localize", data={"map": "imgs", "vehicle_id": "cam", **key},
                        files={"image": (f"{i}.png", png_bytes(i))})  # fmt: skip
        assert r.status_code == 200 and r.json()["adapted"], r.text
        got.append(r.json()["index"])
        key = {"vehicle_key": r.json()["vehicle_key"]}
    assert got == want
    r = client.post("/v1/localize", data={"map": "imgs", "vehicle_id": "cam", "reset": "true", **key},
                    files={"image": ("3.png", png_bytes(3))})  # fmt: skip
    assert r.json()["index"] == int(model.localize(X[:1]).index[0])


def _loaded(version: int, model: object) -> LoadedModel:
    return LoadedModel(map="m", version=version, model=model, info=None, extractor_config=None)  # type: ignore[arg-type]


def test_adapters_restart_with_the_version_and_forget_the_least_recent() -> None:
    route = smooth_route(80, 8, seed=5)  # SYNTHETIC
    model = build_model(ModelParams()).fit(route.reference)
    v1, v2 = _loaded(1, model), _loaded(2, model)
    adapters = VehicleAdapters(max_vehicles=2)
    Q = route.query
    first, key, _ = adapters.adapt(v1, "a", Q[:1])
    a = np.vstack([first] + [adapters.adapt(v1, "a", Q[i : i + 1], key)[0] for i in range(1, 10)])
    assert np.array_equal(a, adapt_drive(model, Q[:10]))
    restarted, same, _ = adapters.adapt(v2, "a", Q[10:11], key)  # a new version: a fresh drive
    assert np.allclose(restarted, Q[10:11], atol=1e-5) and same == key
    adapters.adapt(v1, "b", Q[:1])
    adapters.adapt(v1, "c", Q[:1])
    per_vehicle = 12 * 8 + ADAPTER_OVERHEAD_BYTES + ENTRY_OVERHEAD_BYTES  # float32 mean, var, last
    assert len(adapters) == 2 and adapters.nbytes == 2 * per_vehicle

"""Admin endpoints in-process: auth, upload validation, jobs, versions, activation."""

from __future__ import annotations

import io
import pickle
import zipfile

import numpy as np
from api_helpers import TOKEN, expected_index, npy_bytes
from fastapi.testclient import TestClient

from service.api.app import create_app
from service.core.context import build_context
from service.settings import Settings


def _upload(client: TestClient, auth, name: str, payload: bytes, filename: str = "r.npy", **data):
    return client.post(f"/v1/maps/{name}/routes", headers=auth, files={"file": (filename, payload)},
                       data={"trainer": "ridge", **data})  # fmt: skip


def test_auth_is_required(client: TestClient, route) -> None:
    r = client.get("/v1/maps")
    assert r.status_code == 401 and r.headers["www-authenticate"] == "Bearer"
    r = client.get("/v1/maps", headers={"Authorization": "Bearer wrong"})
    assert r.status_code == 401 and r.json()["message"] == "invalid admin token"
    r = client.get("/v1/maps", headers={"Authorization": f"Bearer {TOKEN}"})
    assert r.status_code == 200 and r.json() == []


def test_admin_disabled_without_token_unless_insecure_dev(tmp_path, registry, backend) -> None:
    for insecure, status in ((False, 403), (True, 200)):
        s = Settings(data_dir=tmp_path, admin_token=None, insecure_dev=insecure)
        with TestClient(create_app(s, context=build_context(s, registry, backend))) as c:
            r = c.get("/v1/maps")
            assert r.status_code == status
            if status == 403:
                assert "GRIDPLACE_ADMIN_TOKEN" in r.json()["message"]


def test_upload_train_list_activate_delete(client: TestClient, auth, route, registry) -> None:
    r = _upload(client, auth, "m", npy_bytes(route[0]))
    assert r.status_code == 202 and r.headers["location"] == f"/v1/jobs/{r.json()['id']}"
    assert r.json()["job_id"] == r.json()["id"]  # the name the README documents
    job = client.get(f"/v1/jobs/{r.json()['id']}", headers=auth).json()
    assert job["state"] == "succeeded" and job["version"] == 1
    assert _upload(client, auth, "m", npy_bytes(route[0][::-1].copy())).status_code == 202
    client.app.state.context.store.refresh()
    maps = client.get("/v1/maps", headers=auth).json()
    assert maps[0]["name"] == "m" and maps[0]["versions"] == [1, 2] and maps[0]["active_version"] == 1
    detail = client.get("/v1/maps/m", headers=auth).json()
    assert detail["active"]["version"] == 1 and detail["serving_version"] == 1
    assert detail["active"]["footprint"]["actual_bytes"] > 0
    assert len(client.get("/v1/maps/m/versions", headers=auth).json()) == 2
    q = route[0][5].tolist()
    before = client.post("/v1/localize", json={"map": "m", "descriptor": q}).json()
    assert before["version"] == 1 and [before["index"]] == expected_index(registry, "m", 1, route[0][5])
    a = client.post("/v1/maps/m/versions/2/activate", headers=auth)
    assert a.status_code == 200 and a.json()["active"] is True
    after = client.post("/v1/localize", json={"map": "m", "descriptor": q}).json()
    assert after["version"] == 2 and [after["index"]] == expected_index(registry, "m", 2, route[0][5])
    assert client.delete("/v1/maps/m/versions/2", headers=auth).status_code == 409
    assert client.delete("/v1/maps/m/versions/1", headers=auth).status_code == 204
    assert client.get("/v1/maps/m/versions/1", headers=auth).status_code == 404
    assert client.get("/v1/jobs/nope", headers=auth).status_code == 404
    assert client.post("/v1/maps/m/versions/9/activate", headers=auth).status_code == 404


def test_idempotency_key_returns_the_same_job(client: TestClient, auth, route, backend) -> None:
    h = {**auth, "Idempotency-Key": "abc-1"}
    a = client.post("/v1/maps/m/routes", headers=h, files={"file": ("r.npy", npy_bytes(route[0]))},
                    data={"trainer": "ridge"})  # fmt: skip
    b = client.post("/v1/maps/m/routes", headers=h, files={"file": ("r.npy", npy_bytes(route[0]))},
                    data={"trainer": "ridge"})  # fmt: skip
    assert a.json()["id"] == b.json()["id"] and len(backend.submitted) == 1


def test_upload_is_stored_by_sha_and_params_reach_the_backend(client, auth, route, backend, settings) -> None:
    r = _upload(client, auth, "m", npy_bytes(route[0]), n_patterns="3", rho="0.4", periods="8,4,4")
    assert r.status_code == 202, r.text
    _, path, params, extractor = backend.submitted[0]
    assert path.parent == settings.data_dir / "uploads" and path.stem and len(path.stem) == 64
    assert params.n_patterns == 3 and params.rho == 0.4 and params.periods == (8, 4, 4)
    assert extractor is None
    np.testing.assert_array_equal(np.load(path), route[0])


def test_bad_uploads_are_4xx_naming_the_problem(client: TestClient, auth, route, settings) -> None:
    cases = [
        (npy_bytes(np.zeros((0, 8))), "r.npy", {}, 400, "empty"),
        (npy_bytes(route[0][:1]), "r.npy", {}, 400, "at least 2 rows"),
        (pickle.dumps({"x": 1}), "r.npy", {}, 400, "neither"),
        (b"\x93NUMPY" + pickle.dumps(1), "r.npy", {}, 400, "not a valid"),
        (b"", "r.npy", {}, 400, "empty"),
        (b"hello world", "r.txt", {}, 400, "neither"),
        (npy_bytes(route[0]), "r.npy", {"rho": "7"}, 422, "rho"),  # the schema's bounds: 422
        (npy_bytes(route[0]), "r.npy", {"trainer": "magic"}, 422, "trainer"),
        (npy_bytes(route[0]), "r.npy", {"n_patterns": "two"}, 422, "n_patterns"),
        (npy_bytes(route[0]), "r.npy", {"extractor": "patchnorm"}, 400, "d=2048"),
        (npy_bytes(route[0]), "r.npy", {"extractor": "sift"}, 422, "extractor"),
        (npy_bytes(route[0]), "r.npy", {"n_chunks": "500"}, 400, "n_chunks"),
    ]
    arr = np.empty(3, dtype=object)
    arr[:] = [1, "a", None]
    buf = io.BytesIO()
    np.save(buf, arr, allow_pickle=True)
    cases.append((buf.getvalue(), "r.npy", {}, 400, "pickled"))
    nan = route[0].copy()
    nan[3, 4] = np.nan
    cases.append((npy_bytes(nan), "r.npy", {}, 400, "NaN"))
    for payload, filename, data, status, needle in cases:
        r = _upload(client, auth, "bad", payload, filename, **data)
        assert r.status_code == status, (needle, r.text)
        assert needle.lower() in r.text.lower(), (needle, r.text)
    assert _upload(client, auth, "bad name!", npy_bytes(route[0])).status_code == 422
    assert not list(settings.data_dir.glob("uploads/*.npy"))  # nothing half-accepted was stored


def test_zip_bomb_and_oversized_bodies_are_413(client: TestClient, auth) -> None:
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", compression=zipfile.ZIP_DEFLATED) as zf:
        zf.writestr("a.png", b"\x00" * (8 * 1024 * 1024))  # 8 MiB of zeros → ~8 KiB
    r = _upload(client, auth, "z", buf.getvalue(), "bomb.zip")
    assert r.status_code == 413 and "upload limit" in r.json()["message"]
    big = b"\x00" * (3 * 1024 * 1024)
    r = _upload(client, auth, "z", big, "big.npy")
    assert r.status_code == 413 and "GRIDPLACE_MAX_UPLOAD_MB" in r.json()["message"]


def test_training_unavailable_is_503_while_localize_answers(client, auth, trained, route, backend) -> None:
    backend.available = False
    r = _upload(client, auth, "m2", npy_bytes(route[0]))
    assert r.status_code == 503 and r.json()["error"] == "unavailable"
    r = client.post("/v1/localize", json={"map": trained, "descriptor": route[0][0].tolist()})
    assert r.status_code == 200
    assert client.get("/metrics").status_code == 200


def test_chunked_body_over_the_limit_is_413(client: TestClient, auth) -> None:
    def chunks():
        for _ in range(3):
            yield b"\x00" * (1024 * 1024)

    boundary = "xyz"
    head = (f"--{boundary}\r\nContent-Disposition: form-data; name=\"file\"; filename=\"r.npy\"\r\n"
            "Content-Type: application/octet-stream\r\n\r\n").encode()  # fmt: skip

    def body():
        yield head
        yield from chunks()
        yield f"\r\n--{boundary}--\r\n".encode()

    r = client.post("/v1/maps/m/routes", content=body(),
                    headers={**auth, "Content-Type": f"multipart/form-data; boundary={boundary}"})  # fmt: skip
    assert r.status_code == 413 and "GRIDPLACE_MAX_UPLOAD_MB" in r.json()["message"]
    public = (b"\x00" * (1024 * 1024) for _ in range(17))  # public routes: their own 16 MiB
    r = client.post("/v1/localize/batch?map=m", content=public,
                    headers={"Content-Type": "application/octet-stream"})  # fmt: skip
    assert r.status_code == 413 and "GRIDPLACE_MAX_PUBLIC_BODY_MB" in r.json()["message"]


def test_unauthenticated_upload_is_refused_before_its_body_is_read(client: TestClient) -> None:
    reads = 0

    def body():
        nonlocal reads
        for _ in range(4):
            reads += 1
            yield b"\x00" * 1024

    r = client.post("/v1/maps/m/routes", content=body(),
                    headers={"Content-Type": "multipart/form-data; boundary=x"})  # fmt: skip
    assert r.status_code == 401
    assert reads <= 1  # the gate answered from the headers


def test_non_integer_periods_are_a_422_naming_them(client, auth, route) -> None:
    r = _upload(client, auth, "m", npy_bytes(route[0]), periods="8,a")
    assert r.status_code == 422 and "periods.1: Input should be a valid integer" in r.json()["message"]

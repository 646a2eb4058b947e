"""A real ``gridplace serve`` process on a free port, driven over HTTP with httpx.

Data is SYNTHETIC (smooth random-process routes, N=300, d=64) plus tiny random PNG frames;
training uses trainer=ridge through the server's own training backend.
"""

from __future__ import annotations

import base64
import io
import threading
import time
import zipfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest
from PIL import Image

from service.api.process import ServerProcess, free_port
from service.encoding.synthetic import smooth_route
from service.imaging import decode_image, make_extractor

pytestmark = pytest.mark.slow
TOKEN = "integration-admin-token"
AUTH = {"Authorization": f"Bearer {TOKEN}"}
N, D = 300, 64
IMG_EXTRACTOR = {"kind": "patchnorm", "width": 32, "height": 16, "patch": 8}
ENV = {"GRIDPLACE_ADMIN_TOKEN": TOKEN, "GRIDPLACE_MAX_UPLOAD_MB": "1",
       "GRIDPLACE_RELOAD_INTERVAL_S": "0.2", "GRIDPLACE_TRAIN_WORKERS": "1"}  # fmt: skip


def _npy(X: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.save(buf, X, allow_pickle=False)
    return buf.getvalue()


def _png(seed: int) -> bytes:
    rng = np.random.default_rng(seed)
    buf = io.BytesIO()
    Image.fromarray(rng.integers(0, 255, (16, 32), dtype=np.uint8)).save(buf, format="PNG")
    return buf.getvalue()


def _upload(c: httpx.Client, name: str, payload: bytes, filename: str = "route.npy",
            headers: dict[str, str] | None = None, **data: str) -> httpx.Response:  # fmt: skip
    return c.post(f"/v1/maps/{name}/routes", headers={**AUTH, **(headers or {})},
                  files={"file": (filename, payload)}, data={"trainer": "ridge", **data})  # fmt: skip


def _wait_job(c: httpx.Client, job_id: str, timeout_s: float = 60) -> dict[str, Any]:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        job = c.get(f"/v1/jobs/{job_id}", headers=AUTH).json()
        if job["state"] in ("succeeded", "failed"):
            return job  # type: ignore[no-any-return]
        time.sleep(0.1)
    raise AssertionError(f"job {job_id} did not finish: {job}")


def _wait_serving(c: httpx.Client, name: str, version: int, timeout_s: float = 20) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        detail = c.get(f"/v1/maps/{name}", headers=AUTH).json()
        if detail.get("serving_version") == version:
            return
        time.sleep(0.05)
    raise AssertionError(f"{name} v{version} never served: {detail}")


def _oracle(data_dir: Path, name: str, version: int, X: np.ndarray) -> list[int]:
    """What the stored artifact answers in-process."""
    from service.registry import Registry

    return Registry(data_dir).load_model(name, version).localize(np.atleast_2d(X)).index.tolist()


@pytest.fixture(scope="module")
def data_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("gridplace-data")


@pytest.fixture(scope="module")
def server(data_dir: Path) -> Iterator[ServerProcess]:
    srv = ServerProcess(data_dir, env=ENV).start()
    try:
        yield srv
    finally:
        srv.stop()


@pytest.fixture(scope="module")
def client(server: ServerProcess) -> Iterator[httpx.Client]:
    with httpx.Client(base_url=server.url, timeout=30) as c:
        yield c


@pytest.fixture(scope="module")
def route() -> tuple[np.ndarray, np.ndarray]:
    r = smooth_route(N, D, seed=11)  # SYNTHETIC
    return r.reference, r.query


@pytest.fixture(scope="module")
def synth(client: httpx.Client, route: tuple[np.ndarray, np.ndarray]) -> dict[str, Any]:
    r = _upload(client, "synth", _npy(route[0]), headers={"Idempotency-Key": "synth-v1"})
    assert r.status_code == 202, r.text
    again = _upload(client, "synth", _npy(route[0]), headers={"Idempotency-Key": "synth-v1"})
    assert again.status_code == 202 and again.json()["id"] == r.json()["id"]
    job = _wait_job(client, r.json()["id"])
    assert job["state"] == "succeeded", job
    _wait_serving(client, "synth", job["version"])
    return job


@pytest.fixture(scope="module")
def imgs(client: httpx.Client) -> dict[str, Any]:
    """An image route (40 tiny PNG frames in a zip) trained with a server-side extractor."""
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as zf:
        for i in range(40):
            zf.writestr(f"frames/frame-{i:04d}.png", _png(i))
    r = _upload(client, "imgs", buf.getvalue(), "frames.zip",
                **{("extractor" if k == "kind" else k): str(v) for k, v in IMG_EXTRACTOR.items()})  # fmt: skip
    assert r.status_code == 202, r.text
    job = _wait_job(client, r.json()["id"])
    assert job["state"] == "succeeded", job
    _wait_serving(client, "imgs", 1)
    return job


@pytest.fixture(scope="module")
def second_version(client: httpx.Client, synth: dict[str, Any], route: tuple[np.ndarray, np.ndarray]) -> dict[str, Any]:
    """Version 2 of ``synth`` (the route reversed); uploading it does not activate it."""
    r = _upload(client, "synth", _npy(route[0][::-1].copy()))
    job = _wait_job(client, r.json()["id"])
    assert job["state"] == "succeeded" and job["version"] == 2
    assert client.get("/v1/maps/synth", headers=AUTH).json()["active_version"] == 1  # not auto
    return job


def _activate(c: httpx.Client, name: str, version: int) -> None:
    a = c.post(f"/v1/maps/{name}/versions/{version}/activate", headers=AUTH)
    assert a.status_code == 200 and a.json()["active"] is True, a.text
    _wait_serving(c, name, version)


def test_upload_trains_a_first_version_that_serves(client: httpx.Client, synth: dict[str, Any]) -> None:
    assert synth["version"] == 1 and synth["finished_at"]
    maps = {m["name"]: m for m in client.get("/v1/maps", headers=AUTH).json()}
    assert "synth" in maps and maps["synth"]["active_version"] in (1, 2)  # 2: another test's
    v = client.get("/v1/maps/synth/versions", headers=AUTH).json()[0]
    assert v["n_frames"] == N and v["n_features"] == D and v["params"]["trainer"] == "ridge"
    assert v["footprint"]["actual_bytes"] > 0 and v["extractor"] is None
    assert client.get("/readyz").status_code == 200


def test_localize_single_batch_b64_binary(client, synth, route, data_dir) -> None:
    _activate(client, "synth", 1)
    ref, qry = route
    Q = qry[:40]
    want = _oracle(data_dir, "synth", 1, Q)
    one = client.post("/v1/localize", json={"map": "synth", "descriptor": Q[0].tolist()}).json()
    assert (one["map"], one["version"], one["index"]) == ("synth", 1, want[0])
    assert 0 <= one["confidence"] <= 1 and one["latency_ms"] > 0
    b64 = base64.b64encode(Q[1].astype("<f4").tobytes()).decode()
    assert client.post("/v1/localize", json={"map": "synth", "descriptor_b64": b64}).json()["index"] == want[1]
    batch = client.post("/v1/localize/batch", json={"map": "synth", "descriptors": Q.tolist()}).json()
    assert batch["n"] == 40 and batch["index"] == want
    binary = client.post(f"/v1/localize/batch?map=synth&d={D}", content=Q.astype("<f4").tobytes(),
                         headers={"Content-Type": "application/octet-stream"})  # fmt: skip
    assert binary.status_code == 200 and binary.json()["index"] == want
    hits = np.abs(np.array(_oracle(data_dir, "synth", 1, ref)) - np.arange(N)) <= 3
    assert hits.mean() > 0.5  # the served model localizes its own route


def test_image_route_and_image_queries(client, imgs, data_dir) -> None:
    version = client.get("/v1/maps/imgs/versions/1", headers=AUTH).json()
    assert version["extractor"] == IMG_EXTRACTOR and version["n_features"] == 32 * 16
    ext = make_extractor(IMG_EXTRACTOR)
    want = _oracle(data_dir, "imgs", 1, ext.extract([decode_image(_png(i)) for i in (5, 6)]))
    one = client.post("/v1/localize", json={"map": "imgs", "image_b64": base64.b64encode(_png(5)).decode()})
    assert one.status_code == 200 and one.json()["index"] == want[0]
    form = client.post("/v1/localize", data={"map": "imgs"}, files={"image": ("q.png", _png(6))})
    assert form.status_code == 200 and form.json()["index"] == want[1]


def _bad_cases() -> list[tuple[str, str, dict[str, Any], int, str]]:
    nan_body = '{"map": "synth", "descriptor": [NaN%s]}' % (", 0.5" * (D - 1))
    inf_body = '{"map": "synth", "descriptor": [Infinity%s]}' % (", 0.5" * (D - 1))
    return [
        ("wrong dimension", "/v1/localize", {"json": {"map": "synth", "descriptor": [0.0] * (D - 1)}}, 400, "model expects 64"),
        ("NaN", "/v1/localize", {"content": nan_body, "headers": {"Content-Type": "application/json"}}, 400, "NaN"),
        ("inf", "/v1/localize", {"content": inf_body, "headers": {"Content-Type": "application/json"}}, 400, "infinite"),
        ("empty body", "/v1/localize", {"content": b"", "headers": {"Content-Type": "application/json"}}, 400, "empty"),
        ("empty binary", "/v1/localize/batch?map=synth", {"content": b"", "headers": {"Content-Type": "application/octet-stream"}}, 400, "empty"),
        ("malformed base64", "/v1/localize", {"json": {"map": "synth", "descriptor_b64": "%%%"}}, 422, "base64"),
        ("non-image bytes", "/v1/localize", {"json": {"map": "imgs", "image_b64": base64.b64encode(b"plain text").decode()}}, 400, "not a decodable image"),
        ("non-image multipart", "/v1/localize", {"data": {"map": "imgs"}, "files": {"image": ("x.png", b"\x00\x01")}}, 400, "not a decodable image"),
        ("missing field", "/v1/localize", {"json": {"descriptor": [1.0]}}, 422, "map"),
        ("unknown map", "/v1/localize", {"json": {"map": "nowhere", "descriptor": [0.0] * D}}, 404, "nowhere"),
    ]  # fmt: skip


@pytest.mark.parametrize("case", _bad_cases(), ids=lambda c: c[0])
def test_bad_queries_are_4xx_naming_the_problem(client, synth, imgs, case) -> None:
    _, path, kwargs, status, needle = case
    r = client.post(path, **kwargs)
    assert r.status_code == status, r.text
    assert needle.lower() in r.json()["message"].lower(), r.text


def test_bad_uploads_are_4xx_naming_the_problem(client, route, data_dir) -> None:
    obj = np.empty(2, dtype=object)
    obj[:] = [{"a": 1}, None]
    pickled = io.BytesIO()
    np.save(pickled, obj, allow_pickle=True)
    bomb = io.BytesIO()
    with zipfile.ZipFile(bomb, "w", compression=zipfile.ZIP_DEFLATED) as zf:
        zf.writestr("a.png", _png(0))
        zf.writestr("b.png", b"\x00" * (16 * 1024 * 1024))
    before = sorted((data_dir / "uploads").glob("*.npy"))
    cases = [
        (pickled.getvalue(), "evil.npy", 400, "pickled"),
        (bomb.getvalue(), "bomb.zip", 413, "limit"),
        (b"\x00" * (1024 * 1024 + 10), "huge.npy", 413, "GRIDPLACE_MAX_UPLOAD_MB"),
        (b"", "empty.npy", 400, "empty"),
        (_npy(np.full((4, D), np.inf, dtype=np.float32)), "inf.npy", 400, "infinite"),
    ]
    for payload, filename, status, needle in cases:
        r = _upload(client, "badmap", payload, filename)
        assert r.status_code == status, (filename, r.text)
        assert needle.lower() in r.json()["message"].lower(), r.text
    assert sorted((data_dir / "uploads").glob("*.npy")) == before  # nothing half-accepted
    assert client.get("/v1/maps/badmap", headers=AUTH).status_code == 404


def test_auth_is_refused_without_the_token(client) -> None:
    assert client.get("/v1/maps").status_code == 401
    assert client.get("/v1/maps", headers={"Authorization": "Bearer nope"}).status_code == 401
    r = client.post("/v1/maps/synth/routes", files={"file": ("r.npy", b"x")})
    assert r.status_code == 401 and r.json()["error"] == "unauthorized"


def test_activation_and_rollback_while_requests_are_in_flight(client, server, second_version, route) -> None:
    _activate(client, "synth", 1)
    failures: list[str] = []
    seen: set[int] = set()
    stop = threading.Event()
    body = {"map": "synth", "descriptors": route[1][:16].tolist()}

    def hammer() -> None:
        with httpx.Client(base_url=server.url, timeout=30) as c:
            while not stop.is_set():
                resp = c.post("/v1/localize/batch", json=body)
                if resp.status_code == 200:
                    seen.add(resp.json()["version"])
                else:
                    failures.append(f"{resp.status_code} {resp.text}")

    threads = [threading.Thread(target=hammer) for _ in range(3)]
    for t in threads:
        t.start()
    try:
        for target in (2, 1, 2, 1, 2):
            a = client.post(f"/v1/maps/synth/versions/{target}/activate", headers=AUTH)
            assert a.status_code == 200 and a.json()["active"] is True
            assert client.post("/v1/localize", json={"map": "synth", "descriptor": route[1][0].tolist()}).json()["version"] == target
            time.sleep(0.15)
    finally:
        stop.set()
        for t in threads:
            t.join()
    assert not failures, failures[:3]
    assert seen == {1, 2}
    assert client.delete("/v1/maps/synth/versions/2", headers=AUTH).status_code == 409  # active


def test_map_without_active_version_is_409(client, imgs) -> None:
    d = client.post("/v1/maps/imgs/deactivate", headers=AUTH)
    try:
        assert d.status_code == 200 and d.json()["active_version"] is None
        r = client.post("/v1/localize", json={"map": "imgs", "descriptor": [0.0] * 512})
        assert r.status_code == 409 and "no active version" in r.json()["message"]
        assert client.get("/readyz").status_code == 200  # a map with nothing active is not awaited
    finally:  # the other tests of this module query the image map
        _activate(client, "imgs", 1)


def test_metrics_cover_requests_localize_models_and_jobs(client, second_version, route) -> None:
    _activate(client, "synth", 2)
    job = _wait_job(client, _upload(client, "metered", _npy(route[0][:100])).json()["id"])
    assert job["state"] == "succeeded", job  # this server process has finished a training job
    assert client.post("/v1/localize", json={"map": "synth", "descriptor": route[1][0].tolist()}).status_code == 200
    assert client.post("/v1/localize", json={"map": "synth", "descriptor": [0.0]}).status_code == 400
    text = client.get("/metrics").text
    for needle in (
        'gridplace_http_requests_total{method="POST",route="/v1/localize",status="200"}',
        'gridplace_http_requests_total{method="POST",route="/v1/localize",status="400"}',
        'gridplace_http_request_seconds_bucket{le=',
        'gridplace_localize_seconds_bucket{input="descriptor",le=',
        'gridplace_active_version{map="synth"} 2.0',
        'gridplace_model_footprint_bytes{kind="paper",map="synth"}',
        "gridplace_loaded_versions",
        "gridplace_queue_depth 0.0",
        'gridplace_training_job_seconds_count{state="succeeded"}',
    ):
        assert needle in text, needle


def test_restart_reloads_the_active_versions(server, client, second_version, route, data_dir) -> None:
    _activate(client, "synth", 2)
    # SIGTERM: a graceful shutdown, then exit 0 (the pool's semaphores released, not leaked)
    assert server.stop() == 0, server.log()
    assert "Traceback" not in server.log() and "leaked" not in server.log(), server.log()
    server.start()
    server.wait_ready(30)
    with httpx.Client(base_url=server.url, timeout=30) as c:
        r = c.post("/v1/localize", json={"map": "synth", "descriptor": route[1][3].tolist()})
        assert r.status_code == 200 and r.json()["version"] == 2
        assert r.json()["index"] == _oracle(data_dir, "synth", 2, route[1][3])[0]


def test_unreachable_redis_refuses_training_but_localize_answers(data_dir, synth, route) -> None:
    env = {**ENV, "GRIDPLACE_REDIS_URL": f"redis://127.0.0.1:{free_port()}/0"}
    with ServerProcess(data_dir, env=env) as srv, httpx.Client(base_url=srv.url, timeout=30) as c:
        srv.wait_ready(30)
        r = _upload(c, "synth", _npy(route[0]))
        assert r.status_code == 503 and r.json()["error"] == "unavailable", r.text
        q = c.post("/v1/localize", json={"map": "synth", "descriptor": route[1][0].tolist()})
        assert q.status_code == 200

"""Memory bounds of every request, against a real ``gridplace serve`` with small limits:
``.npy`` headers that lie, compressed ``.npz`` bombs, public bodies sized for an upload, and
images whose decoded pixels exceed the per-request budget.

Data is SYNTHETIC: a smooth random-process route (N=300, d=64) and random/black PNG frames;
the maps are fitted (trainer=ridge) in the test process and published before the server starts.
"""

from __future__ import annotations

import base64
import io
from collections.abc import Iterator
from pathlib import Path

import httpx
import numpy as np
import pytest
from PIL import Image

from service.api.process import ServerProcess
from service.encoding import ModelParams, build_model
from service.encoding.synthetic import smooth_route
from service.imaging import decode_image, make_extractor

pytestmark = pytest.mark.slow
TOKEN = "bounds-admin-token"
AUTH = {"Authorization": f"Bearer {TOKEN}"}
N, D = 300, 64
MIB = 1024 * 1024
IMG_EXTRACTOR = {"kind": "patchnorm", "width": 32, "height": 16, "patch": 8}
ENV = {"GRIDPLACE_ADMIN_TOKEN": TOKEN, "GRIDPLACE_MAX_UPLOAD_MB": "4",
       "GRIDPLACE_MAX_PUBLIC_BODY_MB": "1", "GRIDPLACE_MAX_REQUEST_MEGAPIXELS": "1",
       "GRIDPLACE_TRAIN_WORKERS": "1"}  # fmt: skip


def _npy(X: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.save(buf, X, allow_pickle=False)
    return buf.getvalue()


def _npz(**arrays: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.savez_compressed(buf, **arrays)  # type: ignore[arg-type]
    return buf.getvalue()


def _lying_npy(shape: tuple[int, ...], data_bytes: int) -> bytes:
    buf = io.BytesIO()
    np.lib.format.write_array_header_1_0(buf, {"descr": "<f4", "fortran_order": False, "shape": shape})
    return buf.getvalue() + b"\0" * data_bytes


def _png(width: int, height: int, seed: int | None = None) -> bytes:
    pixels = (np.zeros((height, width), np.uint8) if seed is None
              else np.random.default_rng(seed).integers(0, 255, (height, width), dtype=np.uint8))  # fmt: skip
    buf = io.BytesIO()
    Image.fromarray(pixels).save(buf, format="PNG")
    return buf.getvalue()


@pytest.fixture(scope="module")
def served(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[ServerProcess, httpx.Client]]:
    from service.registry import Registry

    data_dir = tmp_path_factory.mktemp("bounds")
    params = {"trainer": "ridge", "n_patterns": 2}
    registry = Registry(data_dir)
    route = smooth_route(N, D, seed=9).reference
    registry.publish("desc", build_model(ModelParams.parse(**params)).fit(route), params=params,
                     extractor=None, metrics={})  # fmt: skip
    frames = make_extractor(IMG_EXTRACTOR).extract([decode_image(_png(32, 16, s)) for s in range(40)])
    registry.publish("imgs", build_model(ModelParams.parse(**params)).fit(frames), params=params,
                     extractor=IMG_EXTRACTOR, metrics={})  # fmt: skip
    with ServerProcess(data_dir, env=ENV) as srv, httpx.Client(base_url=srv.url, timeout=60) as c:
        srv.wait_ready(30)
        yield srv, c


@pytest.fixture(scope="module")
def server(served: tuple[ServerProcess, httpx.Client]) -> ServerProcess:
    return served[0]


@pytest.fixture(scope="module")
def client(served: tuple[ServerProcess, httpx.Client]) -> httpx.Client:
    return served[1]


def _upload(c: httpx.Client, payload: bytes, filename: str) -> httpx.Response:
    return c.post("/v1/maps/bounded/routes", headers=AUTH, files={"file": (filename, payload)},
                  data={"trainer": "ridge"})  # fmt: skip


def _uploads(data_dir: Path) -> list[Path]:
    return sorted((data_dir / "uploads").glob("*.npy"))


@pytest.mark.parametrize(("payload", "filename", "status", "needles"), [
    (_lying_npy((100_000_000_000, 2048), 64), "huge-header.npy", 413,
     ("100000000000×2048", "GRIDPLACE_MAX_UPLOAD_MB")),
    (_lying_npy((1000, 64), 100), "short.npy", 400, ("truncated", "256000 bytes")),
    (_npz(descriptors=np.zeros((4096, 512), np.uint8)), "bomb.npz", 413,
     ("as float32", "GRIDPLACE_MAX_UPLOAD_MB")),  # 2 MiB of uint8, 8 MiB as float32
    (_npz(descriptors=np.zeros((3000, 2048), np.uint8)), "bigger.npz", 413,
     ("3000×2048", "upload limit")),  # 6 MiB decompressed from a few kB
    (_npz(descriptors=np.full((10, 4), 1e300)), "overflow.npz", 400, ("beyond-float32",)),
], ids=["npy-huge-header", "npy-truncated", "npz-float32-bomb", "npz-member-bomb", "npz-overflow"])  # fmt: skip
def test_array_uploads_are_checked_before_allocating(client, server, payload, filename, status,
                                                     needles) -> None:  # fmt: skip
    before = _uploads(server.data_dir)
    r = _upload(client, payload, filename)
    assert r.status_code == status, r.text
    for needle in needles:
        assert needle in r.json()["message"], r.text
    assert _uploads(server.data_dir) == before  # nothing half-accepted


def test_a_compressed_npz_within_the_limits_is_stored_exactly(client, server) -> None:
    X = smooth_route(N, D, seed=12).reference.astype(np.float64)
    r = _upload(client, _npz(other=np.zeros(3), descriptors=X), "route.npz")
    assert r.status_code == 202, r.text
    stored = [np.load(p, allow_pickle=False) for p in _uploads(server.data_dir)]
    assert any(s.dtype == np.float32 and np.array_equal(s, X.astype(np.float32)) for s in stored)


def test_public_bodies_have_their_own_limit(client, server) -> None:
    big_json = {"map": "desc", "descriptors": np.zeros((5000, D)).tolist()}  # ≈ 1.2 MiB of JSON
    r = client.post("/v1/localize/batch", json=big_json)
    assert r.status_code == 413, r.text[:300]
    assert "GRIDPLACE_MAX_PUBLIC_BODY_MB" in r.json()["message"], r.text
    binary = np.zeros((5000, D), "<f4").tobytes()  # 1.25 MiB, streamed without a length
    r = client.post("/v1/localize/batch?map=desc", content=iter([binary[:MIB], binary[MIB:]]),
                    headers={"Content-Type": "application/octet-stream"})  # fmt: skip
    assert r.status_code == 413 and "1 MiB" in r.json()["message"], r.text[:300]
    ok = client.post("/v1/localize/batch?map=desc", content=binary[: 4000 * D * 4],
                     headers={"Content-Type": "application/octet-stream"})  # fmt: skip
    assert ok.status_code == 200 and ok.json()["n"] == 4000, ok.text[:300]
    # the admin upload keeps GRIDPLACE_MAX_UPLOAD_MB: 2 MiB is accepted there
    upload = _upload(client, _npy(np.random.default_rng(1).random((2048, 256), np.float32)), "r.npy")
    assert upload.status_code == 202, upload.text


def test_images_beyond_the_pixel_budget_are_413_before_decoding(client) -> None:
    frame = _png(800, 600)  # 0.48 MP each in a few kB; the budget is 1 MP per request
    two = client.post("/v1/localize/batch", data={"map": "imgs"},
                      files=[("images", (f"{i}.png", frame)) for i in range(2)])  # fmt: skip
    assert two.status_code == 200 and two.json()["n"] == 2, two.text[:300]
    three = client.post("/v1/localize/batch", data={"map": "imgs"},
                        files=[("images", (f"{i}.png", frame)) for i in range(3)])  # fmt: skip
    assert three.status_code == 413, three.text[:300]
    assert "GRIDPLACE_MAX_REQUEST_MEGAPIXELS" in three.json()["message"], three.text
    black = base64.b64encode(_png(1200, 1000)).decode()  # 1.2 MP in a few kB of PNG
    one = client.post("/v1/localize", json={"map": "imgs", "image_b64": black})
    assert one.status_code == 413 and "1200000" in one.json()["message"], one.text[:300]

"""REST image uploads and image queries with the CNN extractor (a few SYNTHETIC frames)."""

from __future__ import annotations

import io
import zipfile
from collections.abc import Iterator

import numpy as np
import pytest
from api_helpers import expected_index, npy_bytes, png_bytes
from fastapi.testclient import TestClient

from service.imaging import (
    DEFAULT_PRESET,
    clear_extractor_cache,
    decode_image,
    make_extractor,
    parse_extractor_config,
)
from service.imaging import cnn as cnn_module


def _zip(n: int) -> bytes:
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as zf:
        for i in range(n):
            zf.writestr(f"frames/img-{i:03d}.png", png_bytes(i))
    return buf.getvalue()


@pytest.fixture
def no_torch(monkeypatch: pytest.MonkeyPatch) -> Iterator[None]:
    """As if the ``torch`` extra were not installed (no CNN extractor can be built)."""
    real = cnn_module.importlib.import_module

    def missing(name: str, *args: object) -> object:
        if name.split(".")[0] == "torch":
            raise ImportError(name)
        return real(name, *args)

    clear_extractor_cache()
    monkeypatch.setattr(cnn_module.importlib, "import_module", missing)
    yield
    clear_extractor_cache()


def test_image_route_and_image_queries_use_the_stored_cnn_preset(
    client: TestClient, auth: dict[str, str], registry
) -> None:
    r = client.post("/v1/maps/cnn/routes", headers=auth, files={"file": ("route.zip", _zip(12))},
                    data={"extractor": "cnn", "preset": DEFAULT_PRESET, "trainer": "ridge"})  # fmt: skip
    assert r.status_code == 202, r.text
    assert r.json()["state"] == "succeeded", r.json()
    client.app.state.context.store.refresh()  # type: ignore[attr-defined]
    stored = registry.get_version("cnn", 1).extractor
    assert stored["kind"] == "cnn" and stored["preset"] == DEFAULT_PRESET
    assert stored["weights_sha256"] and stored["layers"]
    ext = make_extractor(stored)

    def want(*ids: int) -> list[int]:
        return expected_index(registry, "cnn", 1, ext.extract([decode_image(png_bytes(i)) for i in ids]))

    one = client.post("/v1/localize", data={"map": "cnn"}, files={"image": ("q.png", png_bytes(5))})
    assert one.status_code == 200, one.text
    assert [one.json()["index"]] == want(5)
    many = client.post("/v1/localize/batch", data={"map": "cnn"},
                       files=[("images", (f"{i}.png", png_bytes(i))) for i in (2, 9)])  # fmt: skip
    assert many.status_code == 200 and many.json()["index"] == want(2, 9)


def test_without_torch_images_answer_503_naming_the_package(
    client: TestClient, auth: dict[str, str], no_torch: None
) -> None:
    r = client.post("/v1/maps/nt/routes", headers=auth, files={"file": ("route.zip", _zip(4))},
                    data={"extractor": "cnn", "trainer": "ridge"})  # fmt: skip
    assert r.status_code == 503, r.text
    assert r.json()["error"] == "unavailable" and "torch" in r.json()["message"]
    assert "gridplace[torch]" in r.json()["message"]
    # descriptors made elsewhere still train a cnn map; its image queries are the 503
    d = parse_extractor_config({"kind": "cnn"}).n_features  # known without building the network
    X = np.random.default_rng(0).standard_normal((30, d)).astype(np.float32)
    r = client.post("/v1/maps/nt/routes", headers=auth, files={"file": ("route.npy", npy_bytes(X))},
                    data={"extractor": "cnn", "trainer": "ridge"})  # fmt: skip
    assert r.status_code == 202 and r.json()["state"] == "succeeded", r.text
    client.app.state.context.store.refresh()  # type: ignore[attr-defined]
    q = client.post("/v1/localize", data={"map": "nt"}, files={"image": ("q.png", png_bytes(1))})
    assert q.status_code == 503 and "torch" in q.json()["message"], q.text
    ok = client.post("/v1/localize", json={"map": "nt", "descriptor": X[3].tolist()})
    assert ok.status_code == 200

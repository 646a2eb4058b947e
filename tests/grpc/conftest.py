"""A real ``gridplace serve`` process (REST + gRPC on free ports, temporary data dir) holding
SYNTHETIC maps published through the registry, driven by ``grpc.aio`` clients.

Maps (trainer=ridge, fitted in the test process and published like a worker does):
``route`` (N=300, d=64), ``imgs`` (60 random PNG frames, patchnorm extractor, d=512),
``parked`` (a version but none active), ``swap`` (gets a second version mid-stream).
"""

from __future__ import annotations

import io
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from service.api.process import ServerProcess, free_port
from service.encoding import ModelParams, build_model
from service.encoding.synthetic import smooth_route
from service.imaging import decode_image, make_extractor

TOKEN = "grpc-test-admin-token"
N, D = 300, 64
IMG_EXTRACTOR = {"kind": "patchnorm", "width": 32, "height": 16, "patch": 8}
PARAMS = {"trainer": "ridge", "n_patterns": 2}


def png(seed: int) -> bytes:
    rng = np.random.default_rng(seed)
    buf = io.BytesIO()
    Image.fromarray(rng.integers(0, 255, (16, 32), dtype=np.uint8)).save(buf, format="PNG")
    return buf.getvalue()


def fit(X: np.ndarray):  # noqa: ANN201 - a PlaceRecognizer
    return build_model(ModelParams.parse(**PARAMS)).fit(X)


def publish(data_dir: Path, name: str, X: np.ndarray, extractor: dict | None = None,
            activate: bool | None = None) -> int:  # fmt: skip
    from service.registry import Registry

    info = Registry(data_dir).publish(name, fit(X), params=PARAMS, extractor=extractor,
                                      metrics={}, activate=activate)  # fmt: skip
    return info.version


@dataclass
class Served:
    srv: ServerProcess
    target: str  # host:port of the gRPC server
    data_dir: Path
    reference: np.ndarray
    query: np.ndarray
    oracle: np.ndarray  # what map 'route' v1 answers in-process for ``query``
    images: list[bytes]
    image_oracle: list[int]


@pytest.fixture(scope="package")
def served(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Served]:
    data_dir = tmp_path_factory.mktemp("gridplace-grpc")
    route = smooth_route(N, D, query_noise=0.3, seed=4)  # SYNTHETIC
    model = fit(route.reference)
    images = [png(s) for s in range(60)]
    extractor = make_extractor(IMG_EXTRACTOR)
    Xi = extractor.extract([decode_image(b, str(i)) for i, b in enumerate(images)])
    publish(data_dir, "route", route.reference)
    publish(data_dir, "imgs", Xi, extractor=IMG_EXTRACTOR)
    publish(data_dir, "parked", route.reference[:100], activate=False)
    publish(data_dir, "swap", route.reference)
    grpc_port = free_port()
    env = {"GRIDPLACE_ADMIN_TOKEN": TOKEN, "GRIDPLACE_GRPC_PORT": str(grpc_port),
           "GRIDPLACE_RELOAD_INTERVAL_S": "0.1", "GRIDPLACE_TRAIN_WORKERS": "1"}  # fmt: skip
    srv = ServerProcess(data_dir, env=env).start()
    try:
        srv.wait_ready(60)
        yield Served(srv, f"127.0.0.1:{grpc_port}", data_dir, route.reference, route.query,
                     model.localize(route.query).index, images,
                     fit(Xi).localize(Xi).index.tolist())  # fmt: skip
    finally:
        srv.stop()

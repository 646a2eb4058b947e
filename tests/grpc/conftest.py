"""A real ``gridplace serve`` process (REST + gRPC on free ports, temporary data dir) holding
SYNTHETIC maps published through the registry (see grpc_helpers.py), driven by ``grpc.aio``
clients."""

from __future__ import annotations

from collections.abc import Iterator

import pytest
from grpc_helpers import IMG_EXTRACTOR, TOKEN, D, N, Served, fit, png, publish

from service.api.process import ServerProcess, free_port
from service.encoding.synthetic import smooth_route
from service.imaging import decode_image, make_extractor


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

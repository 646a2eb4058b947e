"""Several traversals trained by real RQ workers against a real Redis (SYNTHETIC routes):
chunks on different workers see the rows of their places of every traversal."""

from __future__ import annotations

import uuid

import numpy as np
from rq_helpers import _backend, _wait

from service.core.traversal_upload import store_traversals
from service.encoding import ModelParams, build_model
from service.encoding.synthetic import smooth_route
from service.encoding.traversals import as_traversals
from service.registry import RouteSource


def test_chunked_traversals_with_place_indices_on_two_workers(data_dir, redis_url, workers):
    queue = f"q-{uuid.uuid4().hex[:8]}"
    workers(queue, 2)
    backend, registry = _backend(data_dir, redis_url, queue)
    route = smooth_route(400, 32, seed=3)
    keep = np.arange(0, 400, 3)
    X, places = [route.reference, route.query[keep]], [np.arange(400), keep]
    stored = store_traversals(data_dir, as_traversals(X, places), "npy")
    assert stored.places is not None
    source = RouteSource(content_sha256=stored.content_sha256, n_frames=stored.n_places,
                         n_features=stored.n_features, n_traversals=stored.n_traversals,
                         places=str(stored.places.relative_to(data_dir)))  # fmt: skip
    params = ModelParams.parse(trainer="ridge", n_chunks=3)
    job = backend.submit("two-seasons", stored.route, params, None, None, source=source)
    done = _wait(backend, job.id)
    assert done.state == "succeeded", done.error
    info = registry.get_version("two-seasons", done.version or 0)
    assert info.n_traversals == 2 and info.n_frames == 400 and info.metrics["backend"] == "rq"
    served = registry.load_model("two-seasons", done.version or 0)
    local = build_model(params).fit(X, places=places)
    np.testing.assert_array_equal(served.predict(route.query), local.predict(route.query))

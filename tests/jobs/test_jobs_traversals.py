"""The training pipeline on uploads of several traversals (SYNTHETIC routes): the embedded
backend trains them as the library does, unchunked and chunked."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from service.core.traversal_upload import store_traversals
from service.encoding import ModelParams, build_model
from service.encoding.synthetic import smooth_route
from service.encoding.traversals import as_traversals
from service.registry import RouteSource


def _source(data_dir: Path, places: list[np.ndarray] | None) -> tuple[Path, RouteSource, list]:
    route = smooth_route(200, 24, seed=9)  # SYNTHETIC
    n = route.reference.shape[0]
    second = route.query if places is None else route.query[places[1]]
    X = [route.reference, second]
    stored = store_traversals(data_dir, as_traversals(X, places), "npy")
    assert stored.places is not None
    source = RouteSource(content_sha256=stored.content_sha256, n_frames=stored.n_places,
                         n_features=stored.n_features, n_traversals=stored.n_traversals,
                         places=str(stored.places.relative_to(data_dir)))  # fmt: skip
    assert stored.n_places == n
    return stored.route, source, X


@pytest.mark.parametrize("chunks", [1, 3])
@pytest.mark.parametrize("indexed", [False, True])
def test_stored_traversals_train_the_librarys_model(
    backend, registry, data_dir, wait_done, chunks: int, indexed: bool
) -> None:
    places = [np.arange(200), np.arange(0, 200, 2)] if indexed else None
    route, source, X = _source(data_dir, places)
    params = ModelParams.parse(trainer="ridge", n_chunks=chunks)
    name = f"trav-{chunks}-{int(indexed)}"
    job = backend.submit(name, route, params, None, None, source=source)
    done = wait_done(backend, job.id)
    assert done.state == "succeeded", done.error
    info = registry.get_version(name, done.version)
    assert info.n_traversals == 2 and info.n_frames == 200
    assert info.metrics["n_traversals"] == 2
    served = registry.load_model(name, done.version)
    local = build_model(params).fit(X, places=places)
    assert served.n_traversals_ == 2
    np.testing.assert_array_equal(served.predict(X[1]), local.predict(X[1]))


def test_a_job_whose_place_index_is_missing_fails_clearly(backend, data_dir, wait_done) -> None:
    route, source, _ = _source(data_dir, None)
    gone = source.model_copy(update={"places": "uploads/no-such-places.npy",
                                     "content_sha256": "f" * 64})  # fmt: skip
    job = backend.submit("trav-gone", route, ModelParams.parse(trainer="ridge"), None, None,
                         source=gone)  # fmt: skip
    done = wait_done(backend, job.id)
    assert done.state == "failed" and "place-index file" in (done.error or "")

"""Hot swap: activations and rollbacks while requests are in flight never fail a request."""

from __future__ import annotations

import threading
import time

import numpy as np
from api_fakes import FakeRegistry
from fastapi.testclient import TestClient

from service.core.model_store import ModelStore
from service.encoding import ModelParams, build_model
from service.encoding.synthetic import smooth_route


def _publish(registry: FakeRegistry, name: str, X: np.ndarray, activate: bool | None = None) -> int:
    model = build_model(ModelParams(trainer="ridge")).fit(X)
    return registry.publish(name, model, params={}, extractor=None, metrics={}, job_id=None,
                            activate=activate).version  # fmt: skip


def test_store_loads_active_versions_and_polls_for_changes() -> None:
    reg = FakeRegistry()
    X = smooth_route(60, 16, seed=3).reference  # SYNTHETIC
    _publish(reg, "a", X)
    reg.create_empty_map("empty")
    store = ModelStore(reg, reload_interval_s=0.02)
    assert not store.ready()
    store.start()
    try:
        deadline = time.monotonic() + 5
        while not store.ready() and time.monotonic() < deadline:
            time.sleep(0.01)
        assert store.ready() and store.get("a").version == 1 and store.get("empty") is None
        loads = reg.loads
        time.sleep(0.1)
        assert reg.loads == loads  # an unchanged generation loads nothing
        _publish(reg, "a", X[::-1].copy(), activate=True)
        deadline = time.monotonic() + 5
        while store.get("a").version != 2 and time.monotonic() < deadline:
            time.sleep(0.01)
        assert store.get("a").version == 2
        assert store.status()["loaded"] == {"a": 2}
    finally:
        store.stop()


def test_activation_and_rollback_under_load_never_fail(client: TestClient, auth, registry, route) -> None:
    ref = route[0]
    _publish(registry, "hot", ref)
    _publish(registry, "hot", ref[::-1].copy(), activate=False)
    client.app.state.context.store.refresh()
    errors: list[str] = []
    versions: set[int] = set()
    stop = threading.Event()

    def hammer() -> None:
        while not stop.is_set():
            r = client.post("/v1/localize/batch", json={"map": "hot", "descriptors": ref[:8].tolist()})
            if r.status_code != 200:
                errors.append(r.text)
            else:
                versions.add(r.json()["version"])

    threads = [threading.Thread(target=hammer) for _ in range(3)]
    for t in threads:
        t.start()
    try:
        for i in range(10):
            r = client.post(f"/v1/maps/hot/versions/{2 if i % 2 == 0 else 1}/activate", headers=auth)
            assert r.status_code == 200
            time.sleep(0.02)
    finally:
        stop.set()
        for t in threads:
            t.join()
    assert not errors
    assert versions == {1, 2}


def test_a_corrupt_new_version_keeps_the_old_one_serving(monkeypatch) -> None:
    from service.errors import ArtifactError

    reg = FakeRegistry()
    X = smooth_route(60, 16, seed=4).reference  # SYNTHETIC
    _publish(reg, "a", X)
    store = ModelStore(reg, reload_interval_s=0.02)
    store.refresh()
    assert store.ready() and store.get("a").version == 1
    _publish(reg, "a", X[::-1].copy(), activate=True)
    real = reg.load_model

    def broken(name: str, version: int):
        if version == 2:
            raise ArtifactError("sha256 mismatch")
        return real(name, version)

    monkeypatch.setattr(reg, "load_model", broken)
    store.refresh()
    assert store.get("a").version == 1  # still serving
    assert not store.ready() and "sha256 mismatch" in store.status()["errors"]["a"]
    assert store.refresh() is False  # no retry storm right away
    monkeypatch.setattr(reg, "load_model", real)
    assert store.refresh(force=True) and store.get("a").version == 2 and store.ready()

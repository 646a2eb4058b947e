"""Appending traversals to a map version through a real ``gridplace serve`` process: REST,
the Python client and ``gridplace client append`` in its own process; the new version's
record, immutability and checksums; bad input; ``kill -9`` during appends.

Data is SYNTHETIC: a smooth random-process route (N=200, d=64) and a second traversal of it
(the same places with noise), trained with the default parameters.
"""

from __future__ import annotations

import io
import os
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest

from service.api.process import ServerProcess
from service.client import GridplaceClient
from service.encoding.artifacts import sha256_file
from service.encoding.synthetic import smooth_route

pytestmark = pytest.mark.slow
TOKEN = "append-admin-token"
AUTH = {"Authorization": f"Bearer {TOKEN}"}
N, D = 200, 64
ENV = {"GRIDPLACE_ADMIN_TOKEN": TOKEN, "GRIDPLACE_RELOAD_INTERVAL_S": "0.2",
       "GRIDPLACE_TRAIN_WORKERS": "1"}  # fmt: skip


def _npy(X: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.save(buf, X, allow_pickle=False)
    return buf.getvalue()


def _wait_job(c: httpx.Client, job_id: str, timeout_s: float = 120) -> dict[str, Any]:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        job = c.get(f"/v1/jobs/{job_id}", headers=AUTH).json()
        if job["state"] in ("succeeded", "failed"):
            return job  # type: ignore[no-any-return]
        time.sleep(0.1)
    raise AssertionError(f"job {job_id} did not finish: {job}")


def _train(c: httpx.Client, name: str, X: np.ndarray, **data: str) -> int:
    r = c.post(f"/v1/maps/{name}/routes", headers=AUTH, files={"file": ("r.npy", _npy(X))},
               data=data)  # fmt: skip
    assert r.status_code == 202, r.text
    job = _wait_job(c, r.json()["id"])
    assert job["state"] == "succeeded", job
    return int(job["version"])


def _append(c: httpx.Client, name: str, version: int, X: np.ndarray,
            places: np.ndarray | None = None, **data: Any) -> httpx.Response:  # fmt: skip
    files = [("file", ("t.npy", _npy(X)))]
    if places is not None:
        files.append(("places", ("p.npy", _npy(places))))
    return c.post(f"/v1/maps/{name}/versions/{version}/traversals", headers=AUTH, files=files,
                  data=data)  # fmt: skip


@pytest.fixture(scope="module")
def route() -> tuple[np.ndarray, np.ndarray]:
    r = smooth_route(N, D, query_noise=0.5, seed=11)
    return r.reference, r.query


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory, route) -> Iterator[ServerProcess]:
    srv = ServerProcess(tmp_path_factory.mktemp("append"), env=ENV).start()
    try:
        with httpx.Client(base_url=srv.url, timeout=60) as c:
            assert _train(c, "route", route[0]) == 1
        yield srv
    finally:
        srv.stop()


@pytest.fixture(scope="module")
def winter_day(server, route) -> tuple[dict[str, Any], dict[str, Any]]:
    """Version 1 as it was, and the version appending 120 tagged winter rows to it."""
    with httpx.Client(base_url=server.url, timeout=60) as c:
        v1 = c.get("/v1/maps/route/versions/1", headers=AUTH).json()
        r = _append(c, "route", 1, route[1][:120], np.arange(120), tag=["season=winter", "time=day"])
        assert r.status_code == 201, r.text
        return v1, r.json()


def test_an_append_publishes_a_new_version_recording_its_traversals(server, route, winter_day) -> None:
    ref, qry = route
    v1, v2 = winter_day
    with httpx.Client(base_url=server.url, timeout=60) as c:
        assert v2["version"] > 1 and not v2["active"]
        assert v2["n_traversals"] == 2 and v2["n_frames"] == N and v2["n_features"] == D
        assert v2["extra"]["appended_to"] == 1
        first, added = v2["extra"]["traversals"]
        assert first["version"] == 1 and first["content_sha256"] == v1["content_sha256"]
        assert added["rows"] == 120 and added["places"] == [0, 119]
        assert added["tags"] == {"season": "winter", "time": "day"}
        assert v2["extra"]["append"]["whitened"] is True
        # per-condition validation: v1 localising the winter rows before it learnt them
        from service.registry import Registry as _R

        before = _R(server.data_dir).load_model("route", 1).predict(qry[:120])
        want = round(float(np.mean(np.abs(before - np.arange(120)) <= 5)), 4)
        assert v2["metrics"]["conditions"] == {
            "season=winter,time=day": {"rows": 120, "version": 1, "precision_at_5": want}}
        # the version appended to is untouched and both are checksummed artifacts
        assert c.get("/v1/maps/route/versions/1", headers=AUTH).json() == v1
        data_dir = server.data_dir
        for v in (v1, v2):
            tensors = data_dir / "artifacts" / "route" / f"v{v['version']}" / "tensors.safetensors"
            assert sha256_file(tensors) == v["sha256"]
        from service.registry import Registry

        registry = Registry(data_dir)
        appended = registry.load_model("route", v2["version"])
        base = registry.load_model("route", 1)
        held_out = qry[120:]
        truth = np.arange(120, N)
        assert np.mean(np.abs(appended.predict(held_out) - truth) <= 2) > 0.5
        # activated, it answers localize like the stored artifact
        act = c.post(f"/v1/maps/route/versions/{v2['version']}/activate", headers=AUTH)
        assert act.status_code == 200, act.text
        deadline = time.monotonic() + 20
        while c.get("/v1/maps/route", headers=AUTH).json().get("serving_version") != v2["version"]:
            assert time.monotonic() < deadline, "the appended version was never served"
            time.sleep(0.05)
        got = c.post("/v1/localize", json={"map": "route", "descriptor": qry[150].tolist()})
        assert got.status_code == 200 and got.json()["version"] == v2["version"]
        assert got.json()["index"] == int(appended.predict(qry[150:151])[0])


def test_appending_to_an_appended_version_keeps_the_whole_record(server, route, winter_day) -> None:
    _, qry = route
    base = winter_day[1]["version"]
    with GridplaceClient(server.url, token=TOKEN) as gp:
        v = gp.append_traversals("route", base, qry[120:], places=[np.arange(120, N)],
                                 tags=["season=winter"])  # fmt: skip
        assert v.n_traversals == 3 and v.extra["appended_to"] == base
        assert set(v.metrics["conditions"]) == {"season=winter,time=day", "season=winter"}
        assert [t.get("tags") for t in v.extra["traversals"]][1:] == [
            {"season": "winter", "time": "day"}, {"season": "winter"}]  # fmt: skip


BAD = [
    ("width", lambda q: {"X": q[:, :32]}, 400, "d=32"),
    ("places out of range", lambda q: {"X": q[:5], "places": np.array([0, 1, 2, 3, N])},
     400, "beyond the route"),
    ("negative place", lambda q: {"X": q[:3], "places": np.array([0, -1, 2])}, 400, "negative"),
    ("tag without '='", lambda q: {"X": q[:5], "tag": ["winter"]}, 422, "tag"),
    ("empty tag value", lambda q: {"X": q[:5], "tag": ["season="]}, 422, "tag"),
    ("unknown field", lambda q: {"X": q[:5], "trainer": "ridge"}, 422, "trainer"),
]  # fmt: skip


@pytest.mark.parametrize(("case", "make", "status", "text"), BAD, ids=[b[0] for b in BAD])
def test_bad_appends_are_refused_without_a_version(server, route, case, make, status, text) -> None:
    _, qry = route
    with httpx.Client(base_url=server.url, timeout=60) as c:
        before = [v["version"] for v in c.get("/v1/maps/route/versions", headers=AUTH).json()]
        spec = make(qry)
        X, places = spec.pop("X"), spec.pop("places", None)
        r = _append(c, "route", 1, X, places, **spec)
        assert r.status_code == status, r.text
        assert text in r.text
        assert [v["version"] for v in c.get("/v1/maps/route/versions", headers=AUTH).json()] == before
        assert _append(c, "route", 999, qry[:5]).status_code == 404


def test_extending_the_route_keeps_every_index(server, route) -> None:
    ref, _ = route
    more = smooth_route(N + 40, D, seed=12).reference[N:]
    with httpx.Client(base_url=server.url, timeout=60) as c:
        r = _append(c, "route", 1, more, np.arange(N, N + 40))
        assert r.status_code == 400 and "extend" in r.text
        r = _append(c, "route", 1, more, np.arange(N, N + 40), extend="true")
        assert r.status_code == 201, r.text
        v = r.json()
        assert v["n_frames"] == N + 40 and v["extra"]["append"]["extended_from"] == N
    from service.registry import Registry

    model = Registry(server.data_dir).load_model("route", v["version"])
    base = Registry(server.data_dir).load_model("route", 1)
    np.testing.assert_array_equal(model.predict(ref), base.predict(ref))  # existing places keep their answers
    assert np.mean(model.predict(more) >= N) > 0.9


def _cli(server: ServerProcess, *args: str) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "GRIDPLACE_URL": server.url, "GRIDPLACE_ADMIN_TOKEN": TOKEN}
    return subprocess.run([sys.executable, "-m", "service.cli", "client", *args], env=env,
                          capture_output=True, text=True, timeout=120, check=False)  # fmt: skip


def test_gridplace_client_append(server, route, tmp_path: Path) -> None:
    _, qry = route
    a = tmp_path / "a.npy"
    np.save(a, qry[:50], allow_pickle=False)
    out = _cli(server, "append", "route", "1", str(a), "--tag", "season=winter", "--json")
    assert out.returncode == 0, out.stdout + out.stderr
    assert '"appended_to": 1' in out.stdout.replace('":1', '": 1')
    narrow = tmp_path / "narrow.npy"
    np.save(narrow, qry[:50, :10], allow_pickle=False)
    for args, text in [((str(narrow),), "d=10"), ((str(a), "--tag", "winter"), "key=value")]:
        bad = _cli(server, "append", "route", "1", *args)
        assert bad.returncode == 2, bad.stdout + bad.stderr
        assert text in " ".join((bad.stdout + bad.stderr).split())


def test_kill_9_during_appends_leaves_no_partial_version(tmp_path: Path, route) -> None:
    """The server is killed at several moments of an append (upload, update, write, commit):
    after a restart every listed version loads with its checksums, and none is half there."""
    ref, qry = route
    big = np.tile(qry, (8, 1)) + np.float32(0.01)  # 1,600 rows: an append that takes a while
    places = np.tile(np.arange(N), 8)
    from service.registry import Registry

    srv = ServerProcess(tmp_path / "kill", env=ENV)
    srv.start()
    try:
        with httpx.Client(base_url=srv.url, timeout=60) as c:
            _train(c, "route", ref)
        outcomes: list[tuple[float, int, Any]] = []
        for delay in (0.02, 0.08, 0.2, 0.4, 0.8):
            result: list[Any] = []

            def send() -> None:
                try:
                    with httpx.Client(base_url=srv.url, timeout=60) as c:
                        result.append(_append(c, "route", 1, big, places).status_code)
                except httpx.TransportError as exc:
                    result.append(exc)

            t = threading.Thread(target=send)
            t.start()
            time.sleep(delay)
            assert srv.proc is not None
            srv.proc.kill()  # SIGKILL
            srv.proc.wait()
            t.join(30)
            srv.start()
            with httpx.Client(base_url=srv.url, timeout=60) as c:
                listed = c.get("/v1/maps/route/versions", headers=AUTH).json()
            registry = Registry(srv.data_dir)
            for v in listed:  # each loads, its checksums verified
                model = registry.load_model("route", v["version"])
                assert model.n_frames_ == N
            assert listed[0]["version"] == 1 and all(
                v["n_traversals"] == (1 if v["version"] == 1 else 2) for v in listed)  # fmt: skip
            outcomes.append((delay, len(listed), result[0] if result else None))
        print("kill -9 after (s), versions listed, the request's outcome:", outcomes)
    finally:
        srv.stop()


def test_an_extension_the_periods_cannot_label_needs_a_retrain(tmp_path: Path) -> None:
    """A two-digit code whose periods (7, 9) tell 63 places apart cannot take places beyond."""
    from service.registry import Registry

    R = smooth_route(60, D, seed=5).reference
    srv = ServerProcess(tmp_path / "periods", env=ENV).start()
    try:
        with httpx.Client(base_url=srv.url, timeout=60) as c:
            assert _train(c, "res", R, encoder_preset="residue", periods="7,9") == 1
            more = smooth_route(80, D, seed=6).reference[60:72]
            ok = _append(c, "res", 1, more[:3], np.arange(60, 63), extend="true")
            assert ok.status_code == 201, ok.text
            assert ok.json()["n_frames"] == 63
            refused = _append(c, "res", 1, more, np.arange(60, 72), extend="true")
            assert refused.status_code == 409, refused.text
            body = refused.json()
            assert body["error"] == "retrain_required" and "full retrain" in body["message"]
            assert "retrain=true" in body["message"]
            assert [v.version for v in Registry(srv.data_dir).list_versions("res")] == [1, 2]
            # the same form with retrain=true: a job over v2's traversals (v1's upload and the
            # kept rows of its append) and these, with periods chosen for 72 places
            job = _append(c, "res", 2, more[3:], np.arange(63, 72), extend="true",
                          retrain="true", tag="season=winter")  # fmt: skip
            assert job.status_code == 202, job.text
            assert job.headers["location"] == f"/v1/jobs/{job.json()['id']}"
            done = _wait_job(c, job.json()["id"])
            assert done["state"] == "succeeded", done
            v3 = c.get(f"/v1/maps/res/versions/{done['version']}", headers=AUTH).json()
            assert v3["n_frames"] == 72 and v3["n_traversals"] == 3 and v3["job_id"] == done["id"]
            assert v3["extra"]["retrained_from"] == 2 and not v3["active"]
            lineage = v3["extra"]["traversals"]
            assert [t.get("tags") for t in lineage] == [{}, {}, {"season": "winter"}]
            assert all("stored" in t for t in lineage)
            assert c.post("/v1/maps/res/versions/3/activate", headers=AUTH).status_code == 200
            deadline = time.monotonic() + 20
            while c.get("/v1/maps/res", headers=AUTH).json().get("serving_version") != 3:
                assert time.monotonic() < deadline
                time.sleep(0.05)
            named = c.post("/v1/localize/batch", json={"map": "res", "condition": "season=winter",
                                                       "descriptors": more[3:].tolist()})  # fmt: skip
            assert named.status_code == 200 and named.json()["condition"] == "season=winter"
            for bad in ({"whiten": "true"}, {"activate": "true"}):
                r = _append(c, "res", 3, more[:2], np.arange(2), retrain="true", **bad)
                assert r.status_code == 400 and "retrain" in r.json()["message"], r.text
        assert [v.version for v in Registry(srv.data_dir).list_versions("res")] == [1, 2, 3]
    finally:
        srv.stop()


def test_a_retrain_needs_every_traversal_kept(tmp_path: Path) -> None:
    """A version published without a training job keeps no descriptors to retrain from: 409
    naming it; the CLI's --retrain reports it with exit 2."""
    from typer.testing import CliRunner

    from service.cli import app
    from service.encoding import ModelParams, build_model
    from service.registry import Registry

    R = smooth_route(60, D, seed=5).reference
    Registry(tmp_path / "lib").publish("lib", build_model(ModelParams()).fit(R), params={},
                                       extractor=None, metrics={}, activate=True)  # fmt: skip
    srv = ServerProcess(tmp_path / "lib", env=ENV).start()
    try:
        with httpx.Client(base_url=srv.url, timeout=60) as c:
            r = _append(c, "lib", 1, R[:5], np.arange(5), retrain="true")
            assert r.status_code == 409 and "without a training job" in r.json()["message"], r.text
        np.save(tmp_path / "t.npy", R[:5])
        out = CliRunner().invoke(app, ["client", "append", "lib", "1", str(tmp_path / "t.npy"),
                                       "--retrain"],
                                 env={"GRIDPLACE_URL": srv.url, "GRIDPLACE_ADMIN_TOKEN": TOKEN})  # fmt: skip
        assert out.exit_code == 2 and "without a training job" in out.output, out.output
    finally:
        srv.stop()


def test_a_chunked_map_trained_as_a_job_takes_appends(tmp_path: Path, route) -> None:
    """A chunked route trained in parts (the job's workspace keeps the chunk classifier's
    counts) takes an appended traversal; places beyond its chunks need a retrain."""
    ref, qry = route
    srv = ServerProcess(tmp_path / "chunked", env=ENV).start()
    try:
        with httpx.Client(base_url=srv.url, timeout=60) as c:
            assert _train(c, "long", ref, n_chunks="2", trainer="prototype") == 1
            ok = _append(c, "long", 1, qry[:120], np.arange(120), tag="season=winter")
            assert ok.status_code == 201, ok.text
            v2 = ok.json()
            assert v2["kind"] == "chunked_encoder" and v2["n_traversals"] == 2 and v2["n_frames"] == N
            more = smooth_route(N + 5, D, seed=12).reference[N:]
            refused = _append(c, "long", 2, more, np.arange(N, N + 5), extend="true")
            assert refused.status_code == 409 and refused.json()["error"] == "retrain_required"
            assert "retrain=true" in refused.json()["message"]
            # retrained in parts (the chunked job path), the tagged traversals' condition kept
            job = _append(c, "long", 2, more, np.arange(N, N + 5), extend="true", retrain="true",
                          tag="time=night")  # fmt: skip
            assert job.status_code == 202, job.text
            done = _wait_job(c, job.json()["id"])
            assert done["state"] == "succeeded", done
            assert c.post(f"/v1/maps/long/versions/{done['version']}/activate",
                          headers=AUTH).status_code == 200  # fmt: skip
            for condition in ("season=winter", "time=night"):
                r = c.post("/v1/localize/batch", json={"map": "long", "condition": condition,
                                                       "descriptors": more.tolist()})  # fmt: skip
                assert r.status_code == 200 and r.json()["condition"] == condition, r.text
                assert r.json()["version"] == done["version"]
    finally:
        srv.stop()

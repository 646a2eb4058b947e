"""A vehicle driving through the activation of an appended version keeps its place: the
stream's filter and adapter carry into the new version of the same places, and restart (the
answer says so) when the route is extended. Real server (tests/grpc/conftest.py), SYNTHETIC
route, the default model."""

from __future__ import annotations

import asyncio
import io
import time

import grpc
import httpx
import numpy as np
from grpc_helpers import TOKEN, N, Served

from service.encoding import ModelParams, build_model
from service.encoding.synthetic import smooth_route
from service.grpc.gen import localization_pb2 as pb
from service.grpc.gen import localization_pb2_grpc as pb_grpc

AUTH = {"Authorization": f"Bearer {TOKEN}"}


def _npy(X: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.save(buf, X, allow_pickle=False)
    return buf.getvalue()


def _append(url: str, version: int, X: np.ndarray, places: np.ndarray, **data: str) -> int:
    r = httpx.post(f"{url}/v1/maps/fleet/versions/{version}/traversals", headers=AUTH,
                   files=[("file", ("t.npy", _npy(X))), ("places", ("p.npy", _npy(places)))],
                   data={"activate": "true", **data}, timeout=60)  # fmt: skip
    assert r.status_code == 201, r.text
    return int(r.json()["version"])


def test_a_vehicle_keeps_its_place_across_an_appended_version(served: Served) -> None:
    from service.registry import Registry

    R, Q = served.reference, served.query
    Registry(served.data_dir).publish("fleet", build_model(ModelParams()).fit(R), params={},
                                      extractor=None, metrics={}, activate=True)  # fmt: skip
    more = smooth_route(N + 20, R.shape[1], seed=9).reference[N:]
    deadline = time.monotonic() + 20
    while httpx.get(f"{served.srv.url}/v1/maps/fleet", headers=AUTH).json().get("serving_version") != 1:
        assert time.monotonic() < deadline, "map fleet was never served"
        time.sleep(0.05)

    async def go() -> list[pb.StreamResponse]:
        async with grpc.aio.insecure_channel(served.target) as channel:
            call = pb_grpc.LocalizationStub(channel).LocalizeStream()
            got: list[pb.StreamResponse] = []
            appended = extended = 0
            for i in range(N):
                await call.write(pb.StreamRequest(vehicle_id="van", sequence=i, map="fleet",
                                                  sequence_filter=True,
                                                  descriptor=Q[i].astype("<f4").tobytes()))  # fmt: skip
                got.append(await call.read())
                if i == 40:  # a winter traversal of the first half, appended and activated
                    appended = await asyncio.to_thread(_append, served.srv.url, 1, Q[:150],
                                                       np.arange(150), tag="season=winter")  # fmt: skip
                on_v2 = [r for r in got if r.version == appended]
                if appended and not extended and len(on_v2) >= 30:  # the route driven further
                    extended = await asyncio.to_thread(_append, served.srv.url, appended, more,
                                                       np.arange(N, N + 20), extend="true")  # fmt: skip
                if extended and len([r for r in got if r.version == extended]) >= 10:
                    break
            await call.done_writing()
            return got

    got = asyncio.run(go())
    assert not any(r.HasField("error") for r in got)
    versions = [r.version for r in got]
    assert versions == sorted(versions) and versions[0] == 1 and len(set(versions)) == 3
    v2, v3 = sorted(set(versions))[1:]
    first_v2, first_v3 = versions.index(v2), versions.index(v3)
    # carried: the filter goes on combining frames, and the vehicle stays on its place
    assert got[first_v2].vehicle_state == "carried", got[first_v2]
    assert got[first_v2].frames_used == got[first_v2 - 1].frames_used + 1
    on_v2 = got[first_v2:first_v3]
    assert all(abs(r.index - r.sequence) <= 3 for r in on_v2), [(r.sequence, r.index) for r in on_v2]
    assert all(r.adapted for r in got)
    # another number of places: the filter restarts, and the answer says so
    assert got[first_v3].vehicle_state == "restarted" and got[first_v3].frames_used == 1
    assert {r.vehicle_state for i, r in enumerate(got) if i not in (first_v2, first_v3)} == {""}

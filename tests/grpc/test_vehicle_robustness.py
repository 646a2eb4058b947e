"""One wild frame in a drive, through a real ``gridplace serve``: a REST vehicle, a
``/v1/localize/sequence`` drive and a gRPC stream vehicle each send an all-1e6 descriptor at
position 10; every later answer must be the one the same drive gets without it (the frame is
answered, not learnt from). Before, the REST drive's later answers all collapsed onto one
index and the sequence's raw answers went to 0 % within ±5 frames."""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator, Sequence

import grpc
import httpx
import numpy as np
from grpc_helpers import Served

from service.grpc.gen import localization_pb2 as pb
from service.grpc.gen import localization_pb2_grpc as pb_grpc

AT, FRAMES = 10, 150


def _poisoned(Q: np.ndarray) -> np.ndarray:
    return np.insert(Q, AT, np.full(Q.shape[1], 1e6, dtype=np.float32), axis=0)


def _without_poison(answers: Sequence[int]) -> list[int]:
    return [a for i, a in enumerate(answers) if i != AT]


def _precision(index: Sequence[int], truth: np.ndarray) -> float:
    return float(np.mean(np.abs(np.asarray(index) - truth) <= 5))


def test_a_rest_vehicle_is_not_poisoned_by_one_wild_frame(served: Served) -> None:
    Q = served.query[:60].astype(np.float32)

    def drive(rows: np.ndarray, vehicle: str) -> list[int]:
        out, key = [], {}
        with httpx.Client(base_url=served.srv.url, timeout=30) as c:
            for row in rows:
                r = c.post("/v1/localize", json={"map": "route", "descriptor": row.tolist(),
                                                 "vehicle_id": vehicle, **key})  # fmt: skip
                assert r.status_code == 200, r.text
                assert r.json()["adapted"]
                out.append(r.json()["index"])
                key = {"vehicle_key": r.json()["vehicle_key"]}
        return out

    clean = drive(Q, "clean-van")
    poisoned = drive(_poisoned(Q), "poisoned-van")
    assert _without_poison(poisoned) == clean
    assert _precision(clean[AT:], np.arange(AT, Q.shape[0])) >= 0.8


def test_a_sequence_drive_is_not_poisoned_by_one_wild_frame(served: Served) -> None:
    Q = served.query[:FRAMES].astype(np.float32)
    truth = np.arange(AT + 1, FRAMES)

    def post(rows: np.ndarray, adaptation: bool) -> dict:
        r = httpx.post(f"{served.srv.url}/v1/localize/sequence", timeout=60, json={
            "map": "route", "descriptors": rows.tolist(), "adaptation": adaptation})  # fmt: skip
        assert r.status_code == 200, r.text
        return r.json()

    clean, poisoned = post(Q, True), post(_poisoned(Q), True)
    assert poisoned["adapted"]
    assert _without_poison(poisoned["raw_index"]) == clean["raw_index"]
    after = _without_poison(poisoned["raw_index"])[AT + 1 :]
    unadapted = post(_poisoned(Q), False)
    assert _precision(after, truth) >= 0.9 * _precision(_without_poison(unadapted["raw_index"])[AT + 1 :], truth)


def test_a_stream_vehicle_is_not_poisoned_by_one_wild_frame(served: Served) -> None:
    Q = served.query[:80].astype(np.float32)

    def frames(rows: np.ndarray, vehicle: str) -> list[pb.StreamRequest]:
        return [pb.StreamRequest(vehicle_id=vehicle, sequence=i, map="route",
                                 descriptor=r.astype("<f4").tobytes(), adaptation=pb.ADAPTATION_ON)
                for i, r in enumerate(rows)]  # fmt: skip

    async def feed(items: list[pb.StreamRequest]) -> AsyncIterator[pb.StreamRequest]:
        for item in items:
            yield item

    async def run() -> tuple[list[pb.StreamResponse], list[pb.StreamResponse]]:
        async with grpc.aio.insecure_channel(served.target) as channel:
            stub = pb_grpc.LocalizationStub(channel)
            clean = stub.LocalizeStream(feed(frames(Q, "clean")))
            poisoned = stub.LocalizeStream(feed(frames(_poisoned(Q), "poisoned")))
            a, b = await asyncio.gather(_all(clean), _all(poisoned))
            return a, b

    clean, poisoned = asyncio.run(run())
    assert not any(r.HasField("error") for r in clean + poisoned)
    assert _without_poison([r.index for r in poisoned]) == [r.index for r in clean]


async def _all(call: grpc.aio.StreamStreamCall) -> list[pb.StreamResponse]:
    return [r async for r in call]

"""Micro-batching in a real ``gridplace serve``: concurrent gRPC unary calls, stream frames
and REST requests are localized together, and every answer is the one the request gets alone
(the in-process artifact's answer); a bad request in a batch fails alone; order is kept."""

from __future__ import annotations

import asyncio
import base64
import re
from collections.abc import AsyncIterator, Sequence

import grpc
import httpx
import numpy as np
import pytest
from grpc_helpers import D, N, Served

from service.encoding.adaptation import adapt_drive
from service.encoding.sequence import SequenceConfig, SequenceFilter
from service.grpc.gen import localization_pb2 as pb
from service.grpc.gen import localization_pb2_grpc as pb_grpc
from service.registry import Registry

pytestmark = pytest.mark.slow


def f32(x: np.ndarray) -> bytes:
    return np.ascontiguousarray(x, dtype="<f4").tobytes()


def batches_above_one(served: Served) -> int:
    """How many micro-batches so far held more than one request (from /metrics)."""
    text = httpx.get(f"{served.srv.url}/metrics", timeout=10).text
    count = float(re.search(r"^gridplace_localize_batch_size_count (\S+)$", text, re.MULTILINE).group(1))  # type: ignore[union-attr]
    ones = float(re.search(r'^gridplace_localize_batch_size_bucket\{le="1.0"\} (\S+)$', text,
                           re.MULTILINE).group(1))  # type: ignore[union-attr]  # fmt: skip
    return int(count - ones)


def bad_descriptor(i: int) -> bytes:
    if i % 2:
        return f32(np.full(D, np.nan))  # non-finite
    return b"\x00\x00\x80"  # not whole float32 values


def test_concurrent_unary_calls_share_batches_and_answer_as_alone(served: Served) -> None:
    rows = [(5 * i) % N for i in range(240)]
    bad = {17, 18, 101, 202}
    before = batches_above_one(served)

    in_flight = asyncio.Semaphore(96)  # below the server's limit of 128 public requests

    async def call(stub: pb_grpc.LocalizationStub, i: int) -> pb.LocalizeResponse | grpc.aio.AioRpcError:
        data = bad_descriptor(i) if i in bad else f32(served.query[rows[i]])
        async with in_flight:  # at any load: more in flight would be refused
            try:
                return await stub.Localize(pb.LocalizeRequest(map="route", descriptor=data))
            except grpc.aio.AioRpcError as exc:
                return exc

    async def go() -> list[pb.LocalizeResponse | grpc.aio.AioRpcError]:
        async with grpc.aio.insecure_channel(served.target) as channel:
            stub = pb_grpc.LocalizationStub(channel)
            return list(await asyncio.gather(*(call(stub, i) for i in range(len(rows)))))

    got = asyncio.run(go())
    for i, answer in enumerate(got):
        if i in bad:
            assert isinstance(answer, grpc.aio.AioRpcError)
            assert answer.code() == grpc.StatusCode.INVALID_ARGUMENT
        else:
            assert isinstance(answer, pb.LocalizeResponse), answer
            assert answer.matches[0].index == served.oracle[rows[i]]
    assert batches_above_one(served) > before


async def _feed(items: Sequence[pb.StreamRequest]) -> AsyncIterator[pb.StreamRequest]:
    for item in items:
        yield item


def adapted_oracle(served: Served, rows: Sequence[int]) -> np.ndarray:
    """What the map answers in-process for ``rows`` of the query as one vehicle's drive, each
    frame adapted to the frames before it (the stream's default)."""
    model = Registry(served.data_dir).load_model("route", 1)
    Q = served.query[list(rows)].astype(np.float32).astype(np.float64)
    return model.localize(adapt_drive(model, Q)).index


def test_bad_frames_in_shared_batches_fail_alone_and_order_holds(served: Served) -> None:
    """Bad frames fail alone, and they do not move their vehicle's appearance statistics: the
    good frames get the answers of the good frames adapted as one drive in-process."""
    n_streams, per = 8, 150
    before = batches_above_one(served)
    plans = []
    for s in range(n_streams):
        rows = [(11 * s + 3 * i) % N for i in range(per)]
        bad = {i for i in range(per) if (i + s) % 29 == 0}
        items = [pb.StreamRequest(vehicle_id=f"v{s}", sequence=i, map="route",
                                  descriptor=bad_descriptor(i) if i in bad else f32(served.query[r]))
                 for i, r in enumerate(rows)]  # fmt: skip
        plans.append((rows, bad, items))

    async def go() -> list[list[pb.StreamResponse]]:
        async with grpc.aio.insecure_channel(served.target) as channel:
            stub = pb_grpc.LocalizationStub(channel)

            async def one(items: Sequence[pb.StreamRequest]) -> list[pb.StreamResponse]:
                return [r async for r in stub.LocalizeStream(_feed(items))]

            return list(await asyncio.gather(*(one(p[2]) for p in plans)))

    for (rows, bad, items), got in zip(plans, asyncio.run(go()), strict=True):
        assert [r.sequence for r in got] == [q.sequence for q in items]
        good = [i for i in range(per) if i not in bad]
        expected = dict(zip(good, adapted_oracle(served, [rows[i] for i in good]), strict=True))
        for i, r in enumerate(got):
            if i in bad:
                assert r.HasField("error") and r.error.status == "INVALID_ARGUMENT"
            else:
                assert not r.HasField("error") and r.adapted and r.index == expected[i]
    assert batches_above_one(served) > before


def test_a_filtered_vehicle_in_busy_batches_gets_its_unbatched_estimates(served: Served) -> None:
    """Frame scores are computed per frame and the filter runs in frame order, so the
    estimates equal a filter fed one frame at a time in-process."""
    model = Registry(served.data_dir).load_model("route", 1)
    rows = list(range(120))
    Q = adapt_drive(model, served.query[rows].astype(np.float32).astype(np.float64))
    ref = SequenceFilter(N, SequenceConfig())
    expected = [ref.update(model.frame_log_scores(Q[i : i + 1])[0]).index for i in range(len(rows))]
    filtered = [pb.StreamRequest(vehicle_id="filtered", sequence=i, map="route",
                                 descriptor=f32(served.query[r]), sequence_filter=True)
                for i, r in enumerate(rows)]  # fmt: skip
    noise = [[pb.StreamRequest(vehicle_id=f"busy{s}", sequence=i, map="route",
                               descriptor=f32(served.query[(i * 7 + s) % N])) for i in range(200)]
             for s in range(6)]  # fmt: skip

    async def go() -> list[pb.StreamResponse]:
        async with grpc.aio.insecure_channel(served.target) as channel:
            stub = pb_grpc.LocalizationStub(channel)

            async def one(items: Sequence[pb.StreamRequest]) -> list[pb.StreamResponse]:
                return [r async for r in stub.LocalizeStream(_feed(items))]

            got = await asyncio.gather(one(filtered), *(one(b) for b in noise))
            return got[0]

    got = asyncio.run(go())
    assert all(r.filtered for r in got)
    assert [r.index for r in got] == expected
    assert [r.raw_index for r in got] == model.localize(Q).index.tolist()


def test_concurrent_rest_requests_answer_as_alone(served: Served) -> None:
    rows = [(13 * i) % N for i in range(120)]
    before = batches_above_one(served)

    async def one(client: httpx.AsyncClient, i: int) -> dict:
        q = served.query[rows[i]]
        body = ({"map": "route", "descriptor": q.astype(np.float64).tolist()} if i % 2 else
                {"map": "route", "descriptor_b64": base64.b64encode(f32(q)).decode()})  # fmt: skip
        r = await client.post("/v1/localize", json=body)
        assert r.status_code == 200, r.text
        return r.json()  # type: ignore[no-any-return]

    async def go() -> list[dict]:
        async with httpx.AsyncClient(base_url=served.srv.url, timeout=30) as client:
            return list(await asyncio.gather(*(one(client, i) for i in range(len(rows)))))

    got = asyncio.run(go())
    assert [g["index"] for g in got] == served.oracle[rows].tolist()
    batch = httpx.post(f"{served.srv.url}/v1/localize/batch?map=route", content=f32(served.query[rows]),
                       headers={"Content-Type": "application/octet-stream"}, timeout=30).json()  # fmt: skip
    assert batch["index"] == served.oracle[rows].tolist() and batch["n"] == len(rows)
    np.testing.assert_allclose(batch["confidence"], [g["confidence"] for g in got], rtol=1e-5)
    assert batches_above_one(served) > before

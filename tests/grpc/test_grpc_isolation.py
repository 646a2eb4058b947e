"""One caller cannot stall the others: a large unary ``Localize`` runs off the gRPC event loop
while another vehicle's stream keeps being answered, and every method has its own size cap
(defaults: 16 MiB for ``Localize``, 1024 KiB per ``LocalizeStream`` message)."""

from __future__ import annotations

import asyncio
import itertools
import time

import grpc
import numpy as np
import pytest
from grpc_helpers import D, N, Served

from service.grpc.gen import localization_pb2 as pb
from service.grpc.gen import localization_pb2_grpc as pb_grpc

pytestmark = pytest.mark.slow
MIB = 1024 * 1024


def _f32(x: np.ndarray) -> bytes:
    return np.ascontiguousarray(x, dtype="<f4").tobytes()


async def _stream_while(served: Served, channel: grpc.aio.Channel, until: asyncio.Event,
                        answered_at: list[float]) -> None:  # fmt: skip
    """One vehicle, one frame in flight at a time, until ``until`` is set."""
    call = pb_grpc.LocalizationStub(channel).LocalizeStream()
    i = 0
    while not until.is_set():
        await call.write(pb.StreamRequest(vehicle_id="car", sequence=i, map="route",
                                          descriptor=_f32(served.query[i % N])))  # fmt: skip
        reply = await call.read()
        assert not reply.HasField("error"), reply.error
        answered_at.append(time.perf_counter())
        i += 1
    await call.done_writing()
    assert await call.read() is grpc.aio.EOF


def test_a_large_localize_does_not_stall_another_vehicles_stream(served: Served) -> None:
    rows = (12 * MIB) // (4 * D)  # a 12 MiB request, under the 16 MiB default cap
    big = pb.LocalizeRequest(map="route", descriptor=_f32(np.resize(served.query, (rows, D))))

    async def go() -> tuple[float, float, list[float], int]:
        async with grpc.aio.insecure_channel(served.target) as fleet, \
                grpc.aio.insecure_channel(served.target, options=[
                    ("grpc.max_send_message_length", 32 * MIB),
                    ("grpc.max_receive_message_length", 64 * MIB)]) as bulk:  # fmt: skip
            stub = pb_grpc.LocalizationStub(bulk)
            await stub.Localize(pb.LocalizeRequest(map="route", descriptor=_f32(served.query[:1])))
            stop, answered_at = asyncio.Event(), []
            streaming = asyncio.create_task(_stream_while(served, fleet, stop, answered_at))
            while len(answered_at) < 20:  # the stream is warm
                await asyncio.sleep(0.005)
            start = time.perf_counter()
            reply = await stub.Localize(big, timeout=120)
            end = time.perf_counter()
            stop.set()
            await streaming
            return start, end, answered_at, len(reply.matches)

    start, end, answered_at, n = asyncio.run(go())
    assert n == rows
    during = [t for t in answered_at if start <= t <= end]
    times = [start, *during, end]
    longest_wait = max(b - a for a, b in itertools.pairwise(times))
    # the stream went on while the large call ran: no pause near the call's own duration
    assert len(during) >= 5, (len(during), end - start)
    assert longest_wait < 0.5 * (end - start), (longest_wait, end - start)


def test_each_method_has_its_own_size_cap(served: Served) -> None:
    async def go() -> tuple[grpc.aio.AioRpcError, pb.StreamResponse, pb.StreamResponse]:
        async with grpc.aio.insecure_channel(served.target, options=[
                ("grpc.max_send_message_length", 64 * MIB)]) as channel:  # fmt: skip
            stub = pb_grpc.LocalizationStub(channel)
            too_big = pb.LocalizeRequest(map="route", descriptor=bytes(17 * MIB))
            with pytest.raises(grpc.aio.AioRpcError) as refused:
                await stub.Localize(too_big, timeout=60)
            call = stub.LocalizeStream()
            await call.write(pb.StreamRequest(vehicle_id="v", sequence=1, map="route",
                                              descriptor=bytes(2 * MIB)))  # fmt: skip
            oversized = await call.read()
            await call.write(pb.StreamRequest(vehicle_id="v", sequence=2, map="route",
                                              descriptor=_f32(served.query[0])))  # fmt: skip
            after = await call.read()
            await call.done_writing()
            return refused.value, oversized, after

    refused, oversized, after = asyncio.run(go())
    assert refused.code() == grpc.StatusCode.RESOURCE_EXHAUSTED, refused  # refused unread
    assert oversized.error.code == "payload_too_large", oversized
    assert "GRIDPLACE_MAX_STREAM_FRAME_KB" in oversized.error.message, oversized
    assert not after.HasField("error") and after.index == served.oracle[0]  # the stream goes on

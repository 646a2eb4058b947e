"""Server-wide bounds on gRPC streams, against a real ``gridplace serve``: how many streams are
open, how much vehicle state they hold together, and the memory given back when they close
(SYNTHETIC 20,000-frame map: one vehicle's sequence filter holds 560 kB)."""

from __future__ import annotations

import asyncio
import threading
import time
from collections.abc import AsyncIterator, Iterator
from dataclasses import dataclass
from pathlib import Path

import grpc
import numpy as np
import pytest

from service.api.process import ServerProcess, free_port
from service.encoding import ModelParams, build_model
from service.encoding.sequence import SequenceConfig
from service.encoding.synthetic import smooth_route
from service.grpc.gen import localization_pb2 as pb
from service.grpc.gen import localization_pb2_grpc as pb_grpc
from service.registry import Registry

N, D = 20_000, 32
MAX_STREAMS, STATE_MB = 3, 160
FILTER_BYTES = SequenceConfig().n_states * N * 4  # one vehicle's whole-route posterior, float32
PARAMS = {"encoder_preset": "ridge", "trainer": "ridge", "n_patterns": "2"}


@dataclass
class Server:
    srv: ServerProcess
    target: str
    query: np.ndarray

    def rss_mb(self) -> float:
        assert self.srv.proc is not None
        for line in Path(f"/proc/{self.srv.proc.pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
        raise AssertionError("no VmRSS")


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Server]:
    data_dir = tmp_path_factory.mktemp("stream-limits")
    route = smooth_route(N, D, query_noise=0.3, seed=1)  # SYNTHETIC
    model = build_model(ModelParams.parse(**PARAMS)).fit(route.reference)
    Registry(data_dir).publish("long", model, params=PARAMS, extractor=None, metrics={})
    port = free_port()
    env = {"GRIDPLACE_GRPC_PORT": str(port), "GRIDPLACE_TRAIN_WORKERS": "1",
           "GRIDPLACE_MAX_STREAMS": str(MAX_STREAMS), "GRIDPLACE_MAX_STREAM_STATE_MB": str(STATE_MB),
           "GRIDPLACE_MAX_STREAM_VEHICLES": "100000"}  # fmt: skip
    with ServerProcess(data_dir, env=env) as srv:
        srv.wait_ready(60)
        yield Server(srv, f"127.0.0.1:{port}", route.query)


def _frames(Q: np.ndarray, prefix: str, n: int) -> list[pb.StreamRequest]:
    return [pb.StreamRequest(vehicle_id=f"{prefix}-{v}", sequence=v, map="long", sequence_filter=True,
                             descriptor=Q[v % Q.shape[0]].astype("<f4").tobytes())
            for v in range(n)]  # fmt: skip


class _Open:
    """A stream kept open after its frames are answered, until :meth:`close`."""

    def __init__(self, stub: pb_grpc.LocalizationStub, frames: list[pb.StreamRequest]) -> None:
        self.frames, self.done = frames, asyncio.Event()
        self.call = stub.LocalizeStream(self._feed())

    async def _feed(self) -> AsyncIterator[pb.StreamRequest]:
        for f in self.frames:
            yield f
        await self.done.wait()

    async def answers(self) -> list[pb.StreamResponse]:
        return [await self.call.read() for _ in self.frames]

    async def close(self) -> None:
        self.done.set()
        while await self.call.read() is not grpc.aio.EOF:
            pass


class _Peak:
    """The server's largest RSS while the block runs."""

    def __init__(self, server: Server) -> None:
        self.server, self.mb, self._stop = server, server.rss_mb(), threading.Event()

    def __enter__(self) -> _Peak:
        self._thread = threading.Thread(target=self._watch, daemon=True)
        self._thread.start()
        return self

    def _watch(self) -> None:
        while not self._stop.is_set():
            self.mb = max(self.mb, self.server.rss_mb())
            time.sleep(0.02)

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join()


def _settled(server: Server, below_mb: float, timeout_s: float = 10.0) -> float:
    deadline = time.monotonic() + timeout_s
    while (rss := server.rss_mb()) > below_mb and time.monotonic() < deadline:
        time.sleep(0.1)
    return rss


def test_streams_beyond_the_limit_are_refused_and_a_closed_one_frees_its_place(server: Server) -> None:
    async def run() -> None:
        async with grpc.aio.insecure_channel(server.target) as channel:
            stub = pb_grpc.LocalizationStub(channel)
            held = [_Open(stub, _frames(server.query, f"s{i}", 1)) for i in range(MAX_STREAMS)]
            for s in held:
                assert not (await s.answers())[0].HasField("error")
            extra = _Gated(stub, server.query)
            assert not await extra.accepted()  # refused before it sends a frame
            with pytest.raises(grpc.aio.AioRpcError) as refused:
                await extra.call.read()
            assert refused.value.code() == grpc.StatusCode.RESOURCE_EXHAUSTED
            assert "GRIDPLACE_MAX_STREAMS=3" in (refused.value.details() or "")
            assert ("gridplace-error", "capacity_exhausted") in tuple(refused.value.trailing_metadata() or ())
            await held[0].close()
            deadline = time.monotonic() + 5
            while True:  # the closed stream's place is given back as its handler ends
                again = _Gated(stub, server.query)
                if await again.accepted():
                    break
                with pytest.raises(grpc.aio.AioRpcError) as exc:
                    await again.call.read()
                assert exc.value.code() == grpc.StatusCode.RESOURCE_EXHAUSTED
                assert time.monotonic() < deadline
                await asyncio.sleep(0.05)
            assert not (await again.call.read()).HasField("error")
            while await again.call.read() is not grpc.aio.EOF:  # its one frame sent, it ends
                pass
            for s in held[1:]:
                await s.close()

    asyncio.run(run())


class _Gated:
    """A one-frame stream that sends its frame only once the server accepted the stream (its
    initial metadata came), as a careful client does: a frame written while the server
    refuses the stream races its close, which gRPC's Python client reports as INTERNAL."""

    def __init__(self, stub: pb_grpc.LocalizationStub, Q: np.ndarray) -> None:
        self.frames, self.decided, self.open = _frames(Q, "lone", 1), asyncio.Event(), False
        self.call = stub.LocalizeStream(self._feed())

    async def _feed(self) -> AsyncIterator[pb.StreamRequest]:
        await self.decided.wait()
        if self.open:
            for f in self.frames:
                yield f

    async def accepted(self) -> bool:
        metadata = await self.call.initial_metadata()
        self.open = ("gridplace-stream", "open") in tuple(metadata or ())
        self.decided.set()
        return self.open


def test_vehicle_state_is_bounded_server_wide_and_given_back_when_streams_close(server: Server) -> None:
    """Two streams ask for 2 × 300 filtered vehicles (340 MB); the server holds
    GRIDPLACE_MAX_STREAM_STATE_MB (160 MiB) of them and refuses the rest, frame by frame,
    with RESOURCE_EXHAUSTED; its RSS stays within the budget and returns to where it was
    once the streams are closed."""
    time.sleep(0.5)  # the previous test's streams are closed
    baseline = _settled(server, 0.0, 0.0)
    wanted = 300

    async def run() -> list[list[pb.StreamResponse]]:
        async with grpc.aio.insecure_channel(server.target) as channel:
            stub = pb_grpc.LocalizationStub(channel)
            streams = [_Open(stub, _frames(server.query, f"fleet{i}", wanted)) for i in range(2)]
            got = [await s.answers() for s in streams]
            for s in streams:
                await s.close()
            return got

    with _Peak(server) as peak:
        got = asyncio.run(run())
    answers = [a for stream in got for a in stream]
    refused = [a for a in answers if a.HasField("error")]
    held = len(answers) - len(refused)
    budget_mb = STATE_MB * 2**20 / 1e6
    assert 0.8 * budget_mb * 1e6 / FILTER_BYTES <= held <= budget_mb * 1e6 / FILTER_BYTES
    assert {(a.error.status, a.error.code) for a in refused} == {("RESOURCE_EXHAUSTED", "capacity_exhausted")}
    assert "GRIDPLACE_MAX_STREAM_STATE_MB" in refused[0].error.message
    assert peak.mb - baseline <= 1.15 * budget_mb + 30, (baseline, peak.mb)
    after = _settled(server, baseline + 20)
    assert after <= baseline + 20, (baseline, peak.mb, after)

    async def again() -> list[pb.StreamResponse]:  # the budget was given back
        async with grpc.aio.insecure_channel(server.target) as channel:
            s = _Open(pb_grpc.LocalizationStub(channel), _frames(server.query, "later", 50))
            out = await s.answers()
            await s.close()
            return out

    assert not any(a.HasField("error") for a in asyncio.run(again()))

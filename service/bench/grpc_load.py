"""The gRPC load the benchmarks drive a server with (:mod:`service.bench.grpc_bench`,
:mod:`service.bench.batching_grid`): vehicles streaming ``LocalizeStream`` with a bounded
window of unanswered frames, unary ``Localize`` callers, the CPU a process spent meanwhile,
and how alternating rounds merge into one figure.

Every message is built before timing; answers are checked (order, no error) or the
benchmark stops.
"""

from __future__ import annotations

import asyncio
import os
import time
from collections.abc import AsyncIterator, Sequence
from pathlib import Path
from typing import Any

import grpc
import numpy as np

from service.bench.serve_bench import _pct
from service.grpc.gen import localization_pb2 as pb
from service.grpc.gen import localization_pb2_grpc as pb_grpc


def _f32(x: np.ndarray) -> bytes:
    return np.ascontiguousarray(x, dtype="<f4").tobytes()


def stream_requests(Q: np.ndarray, rows: Sequence[int], map_name: str, vehicle: str,
                    seq_filter: bool = False,
                    adaptation: int = pb.ADAPTATION_DEFAULT) -> list[pb.StreamRequest]:  # fmt: skip
    return [pb.StreamRequest(vehicle_id=vehicle, sequence=i, map=map_name, descriptor=_f32(Q[r]),
                             sequence_filter=seq_filter, adaptation=adaptation)  # type: ignore[arg-type]
            for i, r in enumerate(rows)]  # fmt: skip


async def _feed(items: Sequence[pb.StreamRequest]) -> AsyncIterator[pb.StreamRequest]:
    for item in items:
        yield item


def _checked(items: Sequence[pb.StreamRequest], got: list[pb.StreamResponse]) -> list[pb.StreamResponse]:
    """A stream's answers, in order and without errors (or the benchmark stops)."""
    if [r.sequence for r in got] != [q.sequence for q in items]:
        raise AssertionError("stream answers out of order")
    errors = [r.error.message for r in got if r.HasField("error")]
    if errors:
        raise AssertionError(f"{len(errors)} stream errors, e.g. {errors[0]}")
    return got


async def _stream(stub: pb_grpc.LocalizationStub, items: Sequence[pb.StreamRequest]) -> list[pb.StreamResponse]:
    return _checked(items, [r async for r in stub.LocalizeStream(_feed(items))])


async def _windowed(stub: pb_grpc.LocalizationStub, items: Sequence[pb.StreamRequest], window: int,
                    latency: list[float]) -> list[pb.StreamResponse]:  # fmt: skip
    """A vehicle with at most ``window`` frames unanswered; per-frame client-side latency."""
    free = asyncio.Semaphore(window)
    sent: dict[int, float] = {}

    async def feed() -> AsyncIterator[pb.StreamRequest]:
        for item in items:
            await free.acquire()
            sent[item.sequence] = time.perf_counter()
            yield item

    got = []
    async for r in stub.LocalizeStream(feed()):
        latency.append(time.perf_counter() - sent[r.sequence])
        free.release()
        got.append(r)
    return _checked(items, got)


async def run_streams(target: str, batches: list[list[pb.StreamRequest]],
                      window: int = 16) -> tuple[float, list[list[pb.StreamResponse]], list[float]]:  # fmt: skip
    async with grpc.aio.insecure_channel(target) as channel:
        stub = pb_grpc.LocalizationStub(channel)
        await _stream(stub, batches[0][:20])  # warm-up
        latency: list[float] = []
        start = time.perf_counter()
        got = await asyncio.gather(*(_windowed(stub, b, window, latency) for b in batches))
        return time.perf_counter() - start, list(got), latency


async def unary_latency(target: str, Q: np.ndarray, n: int) -> dict[str, Any]:
    async with grpc.aio.insecure_channel(target) as channel:
        stub = pb_grpc.LocalizationStub(channel)
        reqs = [pb.LocalizeRequest(map="bench", descriptor=_f32(Q[i % Q.shape[0]])) for i in range(n + 20)]
        ms = []
        for i, req in enumerate(reqs):
            start = time.perf_counter()
            await stub.Localize(req)
            if i >= 20:
                ms.append((time.perf_counter() - start) * 1000)
    return {"client_ms": _pct(ms), "client_raw": ms}


async def unary_concurrent(target: str, Q: np.ndarray, n: int, concurrency: int) -> dict[str, Any]:
    """``concurrency`` callers, each sending unary requests one after another."""
    async with grpc.aio.insecure_channel(target) as channel:
        stub = pb_grpc.LocalizationStub(channel)
        reqs = [pb.LocalizeRequest(map="bench", descriptor=_f32(Q[i % Q.shape[0]])) for i in range(n)]
        ms: list[float] = []

        async def caller(k: int) -> None:
            for req in reqs[k::concurrency]:
                start = time.perf_counter()
                await stub.Localize(req)
                ms.append((time.perf_counter() - start) * 1000)

        await caller(0)
        ms.clear()
        start = time.perf_counter()
        await asyncio.gather(*(caller(k) for k in range(concurrency)))
        seconds = time.perf_counter() - start
    return {"concurrency": concurrency, "requests": n, "seconds": seconds, "req_per_s": n / seconds,
            "client_ms": _pct(ms), "client_raw": ms}  # fmt: skip


def cpu_seconds(pid: int | None) -> float:
    """User + system CPU seconds of a process so far (Linux ``/proc``; NaN elsewhere)."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    except (OSError, ValueError, IndexError):
        return float("nan")


def stream_throughput(target: str, Q: np.ndarray, period: int, frames: int, n_streams: int,
                      window: int, seq_filter: bool = False,
                      pid: int | None = None) -> dict[str, Any]:  # fmt: skip
    """Frames/s of ``n_streams`` vehicles, and the CPU the server process (``pid``) and this
    client process spent per frame meanwhile (the robust figures on shared cores)."""
    per = frames // n_streams
    rows = [[(s * per + i) % Q.shape[0] for i in range(per)] for s in range(n_streams)]
    batches = [stream_requests(Q, r, "bench", f"vehicle-{s}", seq_filter) for s, r in enumerate(rows)]
    server_cpu, client_cpu = cpu_seconds(pid), time.process_time()
    seconds, got, latency = asyncio.run(run_streams(target, batches, window))
    server_cpu, client_cpu = cpu_seconds(pid) - server_cpu, time.process_time() - client_cpu
    index = np.array([a.index for g in got for a in g])
    truth = np.array([r % period for rr in rows for r in rr])
    return {"streams": n_streams, "frames": per * n_streams, "seconds": seconds,
            "window_per_stream": window, "frames_per_s": per * n_streams / seconds,
            "server_cpu_s": server_cpu, "client_cpu_s": client_cpu,
            "client_ms": _pct([1000 * t for t in latency]),
            "client_raw": [1000 * t for t in latency],
            "server_ms": _pct([a.latency_ms for g in got for a in g]),
            "adapted_fraction": float(np.mean([a.adapted for g in got for a in g])),
            "index": index.tolist(),
            "place_precision_at_5": float(np.mean(np.abs(index % period - truth) <= 5))}  # fmt: skip


def merge_rounds(parts: list[dict[str, Any]]) -> dict[str, Any]:
    """One figure from alternating rounds: rates over the summed time, percentiles over all
    samples."""
    out = dict(parts[-1])
    if "frames_per_s" in out:
        frames, seconds = sum(p["frames"] for p in parts), sum(p["seconds"] for p in parts)
        out.update(frames=frames, seconds=seconds, frames_per_s=frames / seconds,
                   index=[i for p in parts for i in p["index"]])  # fmt: skip
        for side in ("server", "client"):
            cpu = sum(p[f"{side}_cpu_s"] for p in parts)
            out.update({f"{side}_cpu_s": cpu, f"{side}_cpu_us_per_frame": 1e6 * cpu / frames})
    if "req_per_s" in out:
        n, seconds = sum(p["requests"] for p in parts), sum(p["seconds"] for p in parts)
        out.update(requests=n, seconds=seconds, req_per_s=n / seconds)
    if "queries_per_s" in out:
        n, seconds = sum(p["queries"] for p in parts), sum(p["seconds"] for p in parts)
        out.update(queries=n, seconds=seconds, queries_per_s=n / seconds)
    if "client_raw" in out:
        out["client_ms"] = _pct([x for p in parts for x in p["client_raw"]])
        out.pop("client_raw")
    return out



"""gRPC benchmark: a real ``gridplace serve`` (REST + gRPC in one process) on loopback.

* Throughput of ``LocalizeStream``: frames/s on one stream and on ``n_streams`` concurrent
  streams (same total frames), unary ``Localize`` latency, and REST beside them (binary batch
  ``/v1/localize/batch`` and single base64 requests, measured by the service benchmark's own
  functions against the same server). Map: ``bench_data`` of the service benchmark (the real
  Nordland route tiled to ``n_frames``, AUGMENTED, or SYNTHETIC when absent; labelled).
* Sequence filtering: a SYNTHETIC smooth route of ``n_frames`` frames with noisy queries
  (``query_noise``); one vehicle drives it with the stream's ``sequence_filter`` on, another
  with it off, through the real stream; precision@0/2/5 of both and the filtered stream's rate.

Client and server share the machine's cores; the client builds every message before timing.
"""

from __future__ import annotations

import asyncio
import json
import os
import platform
import secrets
import tempfile
import time
from collections.abc import AsyncIterator, Sequence
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import grpc
import httpx
import numpy as np
from rich.console import Console
from rich.table import Table

from service.api.process import ServerProcess, free_port
from service.bench.serve_bench import _batch, _pct, _single, bench_data
from service.encoding import ModelParams, build_model
from service.encoding.synthetic import smooth_route
from service.grpc.gen import localization_pb2 as pb
from service.grpc.gen import localization_pb2_grpc as pb_grpc

console = Console()


def _f32(x: np.ndarray) -> bytes:
    return np.ascontiguousarray(x, dtype="<f4").tobytes()


def _requests(Q: np.ndarray, rows: Sequence[int], map_name: str, vehicle: str,
              seq_filter: bool = False) -> list[pb.StreamRequest]:  # fmt: skip
    return [pb.StreamRequest(vehicle_id=vehicle, sequence=i, map=map_name, descriptor=_f32(Q[r]),
                             sequence_filter=seq_filter) for i, r in enumerate(rows)]  # fmt: skip


async def _feed(items: Sequence[pb.StreamRequest]) -> AsyncIterator[pb.StreamRequest]:
    for item in items:
        yield item


async def _stream(stub: pb_grpc.LocalizationStub, items: Sequence[pb.StreamRequest]) -> list[pb.StreamResponse]:
    got = [r async for r in stub.LocalizeStream(_feed(items))]
    if [r.sequence for r in got] != [q.sequence for q in items]:
        raise AssertionError("stream answers out of order")
    errors = [r.error.message for r in got if r.HasField("error")]
    if errors:
        raise AssertionError(f"{len(errors)} stream errors, e.g. {errors[0]}")
    return got


async def _streams(target: str, batches: list[list[pb.StreamRequest]]) -> tuple[float, list[list[pb.StreamResponse]]]:
    async with grpc.aio.insecure_channel(target) as channel:
        stub = pb_grpc.LocalizationStub(channel)
        await _stream(stub, batches[0][:20])  # warm-up
        start = time.perf_counter()
        got = await asyncio.gather(*(_stream(stub, b) for b in batches))
        return time.perf_counter() - start, list(got)


async def _unary(target: str, Q: np.ndarray, n: int) -> dict[str, Any]:
    async with grpc.aio.insecure_channel(target) as channel:
        stub = pb_grpc.LocalizationStub(channel)
        reqs = [pb.LocalizeRequest(map="bench", descriptor=_f32(Q[i % Q.shape[0]])) for i in range(n + 20)]
        ms = []
        for i, req in enumerate(reqs):
            start = time.perf_counter()
            await stub.Localize(req)
            if i >= 20:
                ms.append((time.perf_counter() - start) * 1000)
    return {"client_ms": _pct(ms)}


def _throughput(target: str, Q: np.ndarray, period: int, frames: int, n_streams: int) -> dict[str, Any]:
    per = frames // n_streams
    rows = [[(s * per + i) % Q.shape[0] for i in range(per)] for s in range(n_streams)]
    batches = [_requests(Q, r, "bench", f"vehicle-{s}") for s, r in enumerate(rows)]
    seconds, got = asyncio.run(_streams(target, batches))
    index = np.array([a.index for g in got for a in g])
    truth = np.array([r % period for rr in rows for r in rr])
    return {"streams": n_streams, "frames": per * n_streams, "seconds": seconds,
            "frames_per_s": per * n_streams / seconds,
            "server_ms": _pct([a.latency_ms for g in got for a in g]),
            "place_precision_at_5": float(np.mean(np.abs(index % period - truth) <= 5))}  # fmt: skip


def _filtering(target: str, Q: np.ndarray, frames: int) -> dict[str, Any]:
    rows = list(range(min(frames, Q.shape[0])))
    batches = [_requests(Q, rows, "noisy", "filtered", True), _requests(Q, rows, "noisy", "raw")]
    seconds_f, (filtered,) = asyncio.run(_streams(target, batches[:1]))
    _, (raw,) = asyncio.run(_streams(target, batches[1:]))
    truth = np.asarray(rows)
    out: dict[str, Any] = {"frames": len(rows), "filtered_frames_per_s": len(rows) / seconds_f}
    for name, answers in (("raw", raw), ("filtered", filtered)):
        err = np.abs(np.array([a.index for a in answers]) - truth)
        out[name] = {f"precision_at_{t}": float(np.mean(err <= t)) for t in (0, 2, 5)}
    return out


def _fit_publish(data_dir: Path, name: str, X: np.ndarray, params: dict[str, str]) -> float:
    from service.registry import Registry

    start = time.perf_counter()
    model = build_model(ModelParams.parse(**params)).fit(X)
    seconds = time.perf_counter() - start
    Registry(data_dir).publish(name, model, params=dict(params), extractor=None, metrics={})
    return seconds


def run_grpc_bench(n_frames: int, frames: int, n_streams: int, rest_batch: int, noise: float,
                   noisy_d: int, params: dict[str, str], out: Path) -> dict[str, Any]:  # fmt: skip
    ref, qry, period, label = bench_data(n_frames)
    noisy = smooth_route(n_frames, noisy_d, query_noise=noise, seed=1)  # SYNTHETIC
    token = secrets.token_hex(16)
    grpc_port = free_port()
    env = {"GRIDPLACE_ADMIN_TOKEN": token, "GRIDPLACE_GRPC_PORT": str(grpc_port),
           "GRIDPLACE_LOG_LEVEL": "warning", "GRIDPLACE_TRAIN_WORKERS": "1"}  # fmt: skip
    target = f"127.0.0.1:{grpc_port}"
    with tempfile.TemporaryDirectory(prefix="gridplace-bench-grpc-") as tmp:
        data_dir = Path(tmp)
        with console.status(f"fitting the {n_frames}-frame maps…"):
            fit_s = _fit_publish(data_dir, "bench", ref, params)
            _fit_publish(data_dir, "noisy", noisy.reference, params)
        with ServerProcess(data_dir, env=env) as srv, httpx.Client(base_url=srv.url, timeout=60) as c:
            srv.wait_ready(120)
            with console.status("measuring gRPC…"):
                unary = asyncio.run(_unary(target, qry, 300))
                one = _throughput(target, qry, period, frames, 1)
                many = _throughput(target, qry, period, frames, n_streams)
                filtering = _filtering(target, noisy.query, frames)
            with console.status("measuring REST on the same server…"):
                rest_batch_out = _batch(c, qry[:frames], rest_batch)
                rest_batch_out.pop("index")
                rest_single = _single(c, qry, 300, as_b64=True)
                rest_single.pop("answers")
    report: dict[str, Any] = {
        "benchmark": "grpc",
        "date": datetime.now(UTC).isoformat(),
        "machine": {"cores": os.cpu_count(), "platform": platform.platform()},
        "data": {"label": label, "N": int(ref.shape[0]), "d": int(ref.shape[1])},
        "filter_data": {"label": f"{noisy.label}, query_noise={noise}", "N": n_frames, "d": noisy_d},
        "params": params,
        "fit_seconds": fit_s,
        "grpc_unary": unary,
        "grpc_stream_1": one,
        f"grpc_streams_{n_streams}": many,
        "rest_batch_binary": rest_batch_out,
        "rest_single_b64": rest_single,
        "sequence_filter": filtering,
        "transport": "loopback, plaintext HTTP/2 (grpc.aio client) and HTTP/1.1 (httpx); "
                     "client and server on the same cores",
    }
    _print(report, n_streams)
    out.write_text(json.dumps(report, indent=2))
    console.print(f"wrote {out}")
    return report


def _print(r: dict[str, Any], n_streams: int) -> None:
    console.print(f"[bold]map:[/] {r['data']['label']} (N={r['data']['N']}, d={r['data']['d']})")
    t = Table(title="gridplace serve — gRPC beside REST, loopback")
    for col in ("measure", "throughput", "p50 ms", "p99 ms"):
        t.add_column(col)
    u = r["grpc_unary"]["client_ms"]
    t.add_row("gRPC unary Localize (sequential)", f"{1000 / u['mean']:.0f} req/s", f"{u['p50']:.2f}", f"{u['p99']:.2f}")
    for key, name in (("grpc_stream_1", "gRPC LocalizeStream, 1 stream"),
                      (f"grpc_streams_{n_streams}", f"gRPC LocalizeStream, {n_streams} streams")):  # fmt: skip
        s = r[key]
        t.add_row(name, f"{s['frames_per_s']:.0f} frames/s", f"{s['server_ms']['p50']:.2f} (server)",
                  f"{s['server_ms']['p99']:.2f} (server)")  # fmt: skip
    b = r["rest_batch_binary"]
    t.add_row(f"REST /v1/localize/batch binary ×{b['batch_size']}", f"{b['queries_per_s']:.0f} q/s", "", "")
    s = r["rest_single_b64"]["client_ms"]
    t.add_row("REST /v1/localize single base64", f"{1000 / s['mean']:.0f} req/s", f"{s['p50']:.2f}", f"{s['p99']:.2f}")
    console.print(t)
    f = r["sequence_filter"]
    console.print(f"[bold]sequence filter[/] on {r['filter_data']['label']} (N={r['filter_data']['N']}, "
                  f"d={r['filter_data']['d']}), {f['frames']} frames along the route:")  # fmt: skip
    for tol in (0, 2, 5):
        console.print(f"  precision@{tol}: raw {f['raw'][f'precision_at_{tol}']:.3f} → "
                      f"filtered {f['filtered'][f'precision_at_{tol}']:.3f}")  # fmt: skip
    console.print(f"  filtered stream: {f['filtered_frames_per_s']:.0f} frames/s")

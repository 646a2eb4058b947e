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
import contextlib
import json
import os
import platform
import secrets
import tempfile
import time
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import httpx
import numpy as np
from rich.console import Console
from rich.table import Table

from service.api.process import ServerProcess, free_port
from service.bench.batching_grid import best_wait, measure_wait_grid
from service.bench.fleet_bound import compute_per_frame
from service.bench.grpc_floor import FloorServer, fleet_efficiency
from service.bench.grpc_load import (
    merge_rounds,
    run_streams,
    stream_requests,
    stream_throughput,
    unary_concurrent,
    unary_latency,
)
from service.bench.serve_bench import _batch, _single, bench_data
from service.encoding import ModelParams, build_model
from service.encoding.synthetic import smooth_route
from service.grpc.gen import localization_pb2 as pb

console = Console()


def _filtering(target: str, Q: np.ndarray, frames: int) -> dict[str, Any]:
    rows = list(range(min(frames, Q.shape[0])))
    # the filter, not adaptation, is measured here: the SYNTHETIC route has no drive-wide shift
    # to adapt to (adaptation would only remove part of its slowly varying scene)
    off = pb.ADAPTATION_OFF
    batches = [stream_requests(Q, rows, "noisy", "filtered", True, off),
               stream_requests(Q, rows, "noisy", "raw", adaptation=off)]  # fmt: skip
    seconds_f, (filtered,), _ = asyncio.run(run_streams(target, batches[:1]))
    _, (raw,), _ = asyncio.run(run_streams(target, batches[1:]))
    truth = np.asarray(rows)
    out: dict[str, Any] = {"frames": len(rows), "filtered_frames_per_s": len(rows) / seconds_f,
                           "adaptation": "off"}  # fmt: skip
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


def _round(target: str, c: httpx.Client, qry: np.ndarray, period: int, frames: int,
           n_streams: int, window: int, rest_batch: int, pid: int | None) -> dict[str, Any]:  # fmt: skip
    out: dict[str, Any] = {
        "grpc_unary": asyncio.run(unary_latency(target, qry, 100)),
        "grpc_unary_concurrent": asyncio.run(unary_concurrent(target, qry, 640, 32)),
        "grpc_stream_1": stream_throughput(target, qry, period, frames, 1, window, pid=pid),
        f"grpc_streams_{n_streams}": stream_throughput(target, qry, period, frames, n_streams,
                                                       window, pid=pid),
        # the same vehicles with the sequence filter on every frame (off by default in a stream)
        f"grpc_streams_{n_streams}_filtered": stream_throughput(
            target, qry, period, frames, n_streams, window, seq_filter=True, pid=pid),
    }
    rest = _batch(c, qry[:frames], rest_batch)
    rest.pop("index")
    out["rest_batch_binary"] = rest
    single = _single(c, qry, 100, as_b64=True, raw=True)
    out["rest_single_b64"] = {"client_raw": single["client_raw"], "client_ms": None}
    return out


def _measure_all(data_dir: Path, token: str, qry: np.ndarray, noisy_q: np.ndarray, period: int,
                 frames: int, n_streams: int, window: int, rest_batch: int, compare: bool,
                 floor: bool, rounds: int = 3) -> tuple[list[dict[str, Any]], dict[str, Any] | None]:  # fmt: skip
    """The micro-batched server, (``compare``) one without batching and (``floor``) the
    do-nothing gRPC server, all up at once, measured in alternating rounds so that all see
    the same load; the floor's streams right after the batched server's in each round."""
    modes = [True, False] if compare else [True]
    with contextlib.ExitStack() as stack:
        servers = []
        for batching in modes:
            port = free_port()
            env = {"GRIDPLACE_ADMIN_TOKEN": token, "GRIDPLACE_GRPC_PORT": str(port),
                   "GRIDPLACE_LOG_LEVEL": "warning", "GRIDPLACE_TRAIN_WORKERS": "1",
                   "GRIDPLACE_BATCHING": "true" if batching else "false"}  # fmt: skip
            srv = stack.enter_context(ServerProcess(data_dir, env=env))
            srv.wait_ready(120)
            client = stack.enter_context(httpx.Client(base_url=srv.url, timeout=60))
            servers.append((f"127.0.0.1:{port}", client, srv.proc.pid if srv.proc else None))
        floor_at = stack.enter_context(FloorServer()) if floor else None
        rounds_out: list[list[dict[str, Any]]] = [[] for _ in modes]
        floor_out: list[dict[str, Any]] = []
        per = max(n_streams, frames // rounds)
        for k in range(rounds):
            for (target, client, pid), got in zip(servers, rounds_out, strict=True):
                with console.status(f"round {k + 1}/{rounds}: measuring {target}…"):
                    got.append(_round(target, client, qry, period, per, n_streams, window,
                                      rest_batch, pid))  # fmt: skip
                if floor_at is not None and got is rounds_out[0]:
                    with console.status(f"round {k + 1}/{rounds}: the gRPC floor…"):
                        floor_out.append(stream_throughput(floor_at[0], qry, period, per,
                                                           n_streams, window, pid=floor_at[1]))
        with console.status("sequence filter through the micro-batched server…"):
            filtering = _filtering(servers[0][0], noisy_q, frames)
    runs = []
    for batching, got in zip(modes, rounds_out, strict=True):
        run = {"batching": batching, **{key: merge_rounds([g[key] for g in got]) for key in got[0]}}
        runs.append(run)
    runs[0]["sequence_filter"] = filtering
    floor_run = None
    if floor_out:
        floor_run = merge_rounds(floor_out)
        floor_run.pop("index")
    return runs, floor_run


def run_grpc_bench(n_frames: int, frames: int, n_streams: int, rest_batch: int, noise: float,
                   noisy_d: int, params: dict[str, str], out: Path, window: int = 16,
                   compare: bool = True, wait_grid: list[float] | None = None,
                   floor: bool = True, grid_frames: int = 15_000) -> dict[str, Any]:  # fmt: skip
    ref, qry, period, label = bench_data(n_frames)
    noisy = smooth_route(n_frames, noisy_d, query_noise=noise, seed=1)  # SYNTHETIC
    token = secrets.token_hex(16)
    with tempfile.TemporaryDirectory(prefix="gridplace-bench-grpc-") as tmp:
        data_dir = Path(tmp)
        with console.status(f"fitting the {n_frames}-frame maps…"):
            fit_s = _fit_publish(data_dir, "bench", ref, params)
            _fit_publish(data_dir, "noisy", noisy.reference, params)
        runs, floor_run = _measure_all(data_dir, token, qry, noisy.query, period, frames, n_streams,
                                       window, rest_batch, compare, floor)  # fmt: skip
        compute = None
        if floor_run is not None:
            with console.status("the fleet's adaptation and localization alone, in process…"):
                compute = _fleet_compute(data_dir, qry, n_streams, window)
        grid = None
        if wait_grid:
            with console.status(f"micro-batch waits {wait_grid} ms…"):
                grid = measure_wait_grid(data_dir, token, qry, period, grid_frames, n_streams,
                                         window, wait_grid)  # fmt: skip
    key = f"grpc_streams_{n_streams}"
    same = None
    if compare:
        same = runs[0][key]["index"] == runs[1][key]["index"]
    for r in runs:
        for k in ("grpc_stream_1", key, f"{key}_filtered"):
            r[k].pop("index")
    report: dict[str, Any] = {
        "benchmark": "grpc",
        "date": datetime.now(UTC).isoformat(),
        "machine": {"cores": os.cpu_count(), "platform": platform.platform()},
        "data": {"label": label, "N": int(ref.shape[0]), "d": int(ref.shape[1])},
        "filter_data": {"label": f"{noisy.label}, query_noise={noise}", "N": n_frames, "d": noisy_d},
        "params": params,
        "fit_seconds": fit_s,
        **runs[0],
        "unbatched": runs[1] if compare else None,
        "batched_answers_equal_unbatched": same,
        "grpc_floor_streams": floor_run,
        "fleet_efficiency": None if floor_run is None else fleet_efficiency(runs[0][key], floor_run,
                                                                            compute),
        "batch_wait_grid": grid,
        "batch_wait_best_ms": None if grid is None else best_wait(grid),
        "transport": "loopback, plaintext HTTP/2 (grpc.aio client) and HTTP/1.1 (httpx); "
                     "client and server on the same cores; stream latency measured by the "
                     f"client with at most {window} frames in flight per stream; stream frames "
                     "adapted by the server's default (GRIDPLACE_DRIVE_ADAPTATION) except the "
                     "sequence-filter drive's; the floor's streams measured right after the "
                     "micro-batched server's in each round",
    }
    _print(report, n_streams)
    out.write_text(json.dumps(report, indent=2))
    console.print(f"wrote {out}")
    return report


def _fleet_compute(data_dir: Path, qry: np.ndarray, n_streams: int, window: int) -> dict[str, Any]:
    """The streams' map, adapted (as the server's default adapts the benchmark's frames) and
    localized in this process, with nothing else."""
    from service.encoding.adaptation import route_statistics
    from service.registry import Registry
    from service.settings import Settings

    registry = Registry(data_dir)
    active = registry.active_version("bench")
    assert active is not None
    model = registry.load_model("bench", active.version)
    settings = Settings()
    adapt = settings.drive_adaptation and route_statistics(model) is not None
    return compute_per_frame(model, qry, n_streams, window, settings.adaptation(), adapt)


def _print(r: dict[str, Any], n_streams: int) -> None:
    console.print(f"[bold]map:[/] {r['data']['label']} (N={r['data']['N']}, d={r['data']['d']})")
    t = Table(title="gridplace serve — gRPC beside REST, loopback (micro-batched | unbatched)")
    for col in ("measure", "throughput", "p50 ms", "p99 ms"):
        t.add_column(col)
    runs = [r] + ([r["unbatched"]] if r.get("unbatched") else [])

    def cells(get: Any) -> list[str]:
        return [" | ".join(get(x)[i] for x in runs) for i in range(3)]

    t.add_row("gRPC unary Localize (sequential)", *cells(lambda x: (
        f"{1000 / x['grpc_unary']['client_ms']['mean']:.0f} req/s",
        f"{x['grpc_unary']['client_ms']['p50']:.2f}", f"{x['grpc_unary']['client_ms']['p99']:.2f}")))
    t.add_row("gRPC unary Localize, 32 concurrent callers", *cells(lambda x: (
        f"{x['grpc_unary_concurrent']['req_per_s']:.0f} req/s",
        f"{x['grpc_unary_concurrent']['client_ms']['p50']:.2f}",
        f"{x['grpc_unary_concurrent']['client_ms']['p99']:.2f}")))
    for key, name in (("grpc_stream_1", "gRPC LocalizeStream, 1 stream (client ms)"),
                      (f"grpc_streams_{n_streams}", f"gRPC LocalizeStream, {n_streams} streams (client ms)"),
                      (f"grpc_streams_{n_streams}_filtered",
                       f"  the same {n_streams} with the sequence filter on")):  # fmt: skip
        t.add_row(name, *cells(lambda x, key=key: (
            f"{x[key]['frames_per_s']:.0f} frames/s (CPU/frame: server "
            f"{x[key]['server_cpu_us_per_frame']:.0f} µs, client {x[key]['client_cpu_us_per_frame']:.0f} µs)",
            f"{x[key]['client_ms']['p50']:.2f}", f"{x[key]['client_ms']['p99']:.2f}")))
    t.add_row(f"REST /v1/localize/batch binary ×{r['rest_batch_binary']['batch_size']}", *cells(
        lambda x: (f"{x['rest_batch_binary']['queries_per_s']:.0f} q/s", "", "")))
    t.add_row("REST /v1/localize single base64", *cells(lambda x: (
        f"{1000 / x['rest_single_b64']['client_ms']['mean']:.0f} req/s",
        f"{x['rest_single_b64']['client_ms']['p50']:.2f}", f"{x['rest_single_b64']['client_ms']['p99']:.2f}")))
    console.print(t)
    if r.get("batched_answers_equal_unbatched") is not None:
        console.print(f"{n_streams}-stream answers identical batched and unbatched: "
                      f"{r['batched_answers_equal_unbatched']}")  # fmt: skip
    if r.get("grpc_floor_streams"):
        fl = r["grpc_floor_streams"]
        console.print(f"gRPC floor, {n_streams} streams against a server that does no work: "
                      f"{fl['frames_per_s']:.0f} frames/s, p50 {fl['client_ms']['p50']:.1f} ms, "
                      f"p99 {fl['client_ms']['p99']:.1f} ms; CPU/frame server "
                      f"{fl['server_cpu_us_per_frame']:.0f} µs, client {fl['client_cpu_us_per_frame']:.0f} µs")  # fmt: skip
        fe = r["fleet_efficiency"]
        console.print(f"[bold]fleet efficiency[/]: server CPU per frame, {n_streams} streams "
                      f"({fe['adapted_fraction']:.0%} of frames adapted), {fe['ratio']:.2f}× the "
                      f"floor's (target ≤ {fe['target_ratio']}×)")  # fmt: skip
        if fe.get("compute"):
            c = fe["compute"]
            console.print(f"  its least possible on this transport: {fe['lower_bound_ratio']:.2f}× "
                          f"(the floor's {fe['floor_server_cpu_us_per_frame']:.0f} µs + adapting "
                          f"{c['adapt_us_per_frame']:.1f} µs + localizing "
                          f"{c['localize_us_per_frame']:.1f} µs per frame, in process at batches "
                          f"of {c['batch']}, nothing else)")  # fmt: skip
    if r.get("batch_wait_grid"):
        g = Table(title=f"GRIDPLACE_BATCH_MAX_WAIT_MS, {n_streams} streams (alternating rounds)")
        for col in ("wait ms", "frames/s", "p50 / p99 ms", "server CPU µs/frame", "unary p50 ms",
                    "mean batch"):  # fmt: skip
            g.add_column(col)
        for wait, v in r["batch_wait_grid"].items():
            cm = v["streams"]["client_ms"]
            g.add_row(wait, f"{v['streams']['frames_per_s']:.0f}", f"{cm['p50']:.1f} / {cm['p99']:.1f}",
                      f"{v['streams']['server_cpu_us_per_frame']:.0f}",
                      f"{v['unary_sequential_client_ms']['p50']:.2f}", f"{v['mean_batch_size']:.1f}")
        console.print(g)
        console.print(f"best wait: {r['batch_wait_best_ms']} ms")
    f = r["sequence_filter"]
    console.print(f"[bold]sequence filter[/] on {r['filter_data']['label']} (N={r['filter_data']['N']}, "
                  f"d={r['filter_data']['d']}), {f['frames']} frames along the route, appearance "
                  "adaptation off (no drive-wide shift to adapt to):")  # fmt: skip
    for tol in (0, 2, 5):
        console.print(f"  precision@{tol}: raw {f['raw'][f'precision_at_{tol}']:.3f} → "
                      f"filtered {f['filtered'][f'precision_at_{tol}']:.3f}")  # fmt: skip
    console.print(f"  filtered stream: {f['filtered_frames_per_s']:.0f} frames/s")

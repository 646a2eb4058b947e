"""The micro-batcher's wait (``GRIDPLACE_BATCH_MAX_WAIT_MS``) measured on a small grid.

One ``gridplace serve`` per wait value, all up at once and measured in alternating rounds (so
that all see the same load): ``n_streams`` concurrent ``LocalizeStream`` vehicles (frames/s,
client-side per-frame latency), sequential unary ``Localize`` calls (what a lone caller pays
for the wait: a batch's first request waits for company up to the wait) and the mean batch
size the server's metrics recorded. Used by ``gridplace bench grpc --wait-grid``.
"""

from __future__ import annotations

import asyncio
import contextlib
import re
from pathlib import Path
from typing import Any

import httpx
import numpy as np

from service.api.process import ServerProcess, free_port


def _mean_batch(url: str) -> float:
    text = httpx.get(f"{url}/metrics", timeout=10).text
    found = {k: re.search(rf"^gridplace_localize_batch_size_{k} (\S+)$", text, re.MULTILINE)
             for k in ("sum", "count")}  # fmt: skip
    if found["sum"] is None or found["count"] is None:
        return float("nan")
    count = float(found["count"].group(1))
    return float(found["sum"].group(1)) / count if count else float("nan")


def measure_wait_grid(data_dir: Path, token: str, qry: np.ndarray, period: int, frames: int,
                      n_streams: int, window: int, waits_ms: list[float],
                      rounds: int = 5) -> dict[str, Any]:  # fmt: skip
    """Per wait (ms, as a string key; the shortest also as ``"<ms> (repeat)"``, a second
    identical server): merged stream throughput and unary latency."""
    from service.bench.grpc_load import merge_rounds, stream_throughput, unary_latency

    with contextlib.ExitStack() as stack:
        servers = []
        # the shortest wait twice: how far two identical servers differ (an A/A control)
        for wait in [*waits_ms, min(waits_ms)]:
            port = free_port()
            env = {"GRIDPLACE_ADMIN_TOKEN": token, "GRIDPLACE_GRPC_PORT": str(port),
                   "GRIDPLACE_LOG_LEVEL": "warning", "GRIDPLACE_TRAIN_WORKERS": "1",
                   "GRIDPLACE_BATCHING": "true", "GRIDPLACE_BATCH_MAX_WAIT_MS": str(wait)}  # fmt: skip
            srv = stack.enter_context(ServerProcess(data_dir, env=env))
            srv.wait_ready(120)
            servers.append((wait, f"127.0.0.1:{port}", srv.url, srv.proc.pid if srv.proc else None))
        keys = [f"{w:g}" for w in waits_ms] + [f"{min(waits_ms):g} (repeat)"]
        got: dict[str, list[dict[str, Any]]] = {k: [] for k in keys}
        per = max(n_streams, frames // rounds)
        for _ in range(rounds):
            for key, (_wait, target, _url, pid) in zip(keys, servers, strict=True):
                streams = stream_throughput(target, qry, period, per, n_streams, window, pid=pid)
                got[key].append({"streams": streams,
                                 "unary": asyncio.run(unary_latency(target, qry, 100))})  # fmt: skip
        out = {}
        for key, (_wait, _target, url, _pid) in zip(keys, servers, strict=True):
            parts = got[key]
            streams = merge_rounds([p["streams"] for p in parts])
            streams.pop("index")
            out[key] = {
                "streams": streams,
                "rounds_frames_per_s": [p["streams"]["frames_per_s"] for p in parts],
                "unary_sequential_client_ms":
                    merge_rounds([p["unary"] for p in parts])["client_ms"],
                "mean_batch_size": _mean_batch(url),
            }
    return out


def best_wait(grid: dict[str, Any]) -> str:
    """The shortest wait, unless a longer one's stream throughput beats it by more than the
    noise: the spread of the shortest wait's rounds, or how far its repeat (a second,
    identical server) lies from it, whichever is larger. Every wait costs a lone caller up to
    the wait, for certain."""
    waits = [k for k in grid if not k.endswith("(repeat)")]
    shortest = min(waits, key=float)
    rate = {k: grid[k]["streams"]["frames_per_s"] for k in grid}
    rounds = grid[shortest]["rounds_frames_per_s"]
    noise = max(rounds) - min(rounds)
    repeat = f"{shortest} (repeat)"
    if repeat in grid:
        noise = max(noise, abs(rate[repeat] - rate[shortest]))
    fastest = max(waits, key=rate.__getitem__)
    return fastest if rate[fastest] - rate[shortest] > noise else shortest

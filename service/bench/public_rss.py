"""``gridplace bench public-rss``: what unauthenticated callers can make a server hold, measured
against the bound docs/RELIABILITY.md states as a formula of the settings.

A real ``gridplace serve`` (its defaults, or the settings given) serves a SYNTHETIC map of
``n_frames`` frames (and a short wide one for REST vehicles and JSON batches, whose cost
is by d). After a warm-up of one request of each kind the bench takes the server's
RSS (psutil, the whole process tree) as its baseline, then runs the worst public load at once
(:mod:`service.bench.public_load`): REST vehicles filling their store, every gRPC stream the
server allows with as many filtered vehicles as it takes, held open; then for ``seconds``
drives with the dearest filter at the work budget, JSON batches at the body limit and bodies
that never end, together filling the public request budget. RSS is sampled every 20 ms; the
report is the peak above the baseline beside :func:`rss_bound` at those settings.
"""

from __future__ import annotations

import base64
import json
import platform
import tempfile
import threading
import time
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import psutil

from service.api.process import ServerProcess, free_port
from service.bench import public_load as load
from service.harness.runner import write_atomic
from service.settings import Settings

MIB = 2**20
THREADS = 40  # Starlette's worker threads (anyio's default limiter): requests computing at once
#: what one request's scoring holds at most: a block of 4 M frame scores (sequence._SCORE_BUDGET,
#: serving_plan._BLOCK_SCORES) with its temporaries, 32 bytes a score (tracemalloc: 128 MiB)
SCORE_SCRATCH_MIB = 128
#: a drive's filter per state and route frame: its posterior, prediction and scratch (float32)
#: and its float64 joint
FILTER_BYTES_PER_STATE_FRAME = 20


def rss_bound(settings: Settings, n_frames: int) -> dict[str, float]:
    """The bound on what public callers can make the server hold beyond its baseline (MiB),
    term by term (``n_frames``: the longest served route)."""
    # REST's worker threads, gRPC's (unary calls and stream frames) and the micro-batcher's
    computing = min(settings.max_public_requests, THREADS) + settings.grpc_workers + 1
    drive_mib = FILTER_BYTES_PER_STATE_FRAME * load.WORST_STATES * n_frames / MIB
    terms = {
        "stream_state": float(settings.max_stream_state_mb),
        "stream_buffers": settings.max_streams * (4 + settings.max_stream_frame_kb / 1024),
        "rest_vehicles": float(settings.rest_vehicle_state_mb),
        "public_bodies_parsed": 12.0 * settings.max_public_bodies_mb,
        "requests_computing": computing * (SCORE_SCRATCH_MIB + drive_mib),
    }
    return {**terms, "total": sum(terms.values())}


class TreeRss:
    """The peak RSS of a process and its descendants, sampled on a thread."""

    def __init__(self, pid: int, every_s: float = 0.02) -> None:
        self.proc, self.every_s = psutil.Process(pid), every_s
        self.peak = self.now()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._watch, daemon=True)

    def now(self) -> int:
        total = 0
        for p in [self.proc, *self.proc.children(recursive=True)]:
            try:
                total += p.memory_info().rss
            except psutil.Error:
                pass
        return total

    def _watch(self) -> None:
        while not self._stop.is_set():
            self.peak = max(self.peak, self.now())
            time.sleep(self.every_s)

    def __enter__(self) -> TreeRss:
        self.peak = self.now()
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join()


def _publish(data: Path, n_frames: int, vehicle_d: int) -> tuple[np.ndarray, np.ndarray]:
    """Two SYNTHETIC maps: ``long`` (``n_frames`` × 16: drives and stream filters cost by N,
    their bodies stay small) and ``wide`` (1,000 × ``vehicle_d``: REST vehicles' statistics
    and a body's parse cost by d). Their queries."""
    from service.encoding import ModelParams, build_model
    from service.encoding.synthetic import smooth_route
    from service.registry import Registry

    registry, params, queries = Registry(data), ModelParams.parse(), []
    for name, n, d in (("long", n_frames, 16), ("wide", 1000, vehicle_d)):
        route = smooth_route(n, d, query_noise=0.3, seed=11)
        registry.publish(name, build_model(params).fit(route.reference),
                         params=params.model_dump(mode="json"), extractor=None, metrics={},
                         job_id=None)  # fmt: skip
        queries.append(route.query.astype(np.float32))
    return queries[0], queries[1]


def _warm_up(url: str, target: str, long: np.ndarray, wide: np.ndarray) -> None:
    """One request of each kind, so that what they load once is in the baseline."""
    row = base64.b64encode(wide[0].astype("<f4").tobytes()).decode()
    with httpx.Client(base_url=url, timeout=120) as c:
        c.post("/v1/localize", json={"map": "wide", "vehicle_id": "warm", "descriptor_b64": row})
        c.post("/v1/localize/batch", json={"map": "wide", "descriptors": wide[:4].tolist()})
        c.post(**load.drive_request("long", long, 4))  # type: ignore[arg-type]
    streams = load.HeldStreams(target, "long", long, 1, window=1).start()
    streams.wait_filled(120)
    streams.close()


def run_public_rss_bench(n_frames: int, vehicle_d: int, seconds: float, env: dict[str, str],
                         out: Path | None, rest_vehicles: int | None = None) -> dict[str, Any]:  # fmt: skip
    """Run the load; return (and write to ``out``) the report. The server's data (its maps)
    lives in a temporary directory, removed afterwards."""
    with tempfile.TemporaryDirectory(prefix="gridplace-public-rss-") as tmp:
        return _measure(Path(tmp), n_frames, vehicle_d, seconds, env, out, rest_vehicles)


def _measure(data: Path, n_frames: int, vehicle_d: int, seconds: float, env: dict[str, str],
             out: Path | None, rest_vehicles: int | None) -> dict[str, Any]:  # fmt: skip
    settings = Settings.model_validate(
        {k.removeprefix("GRIDPLACE_").lower(): v for k, v in env.items()}
    )
    bound = rss_bound(settings, n_frames)
    drive_frames = int(settings.max_request_work * 1e6 // (n_frames * (load.WORST_STATES + 8)))
    long, wide = _publish(data, n_frames, vehicle_d)
    port = free_port()
    report: dict[str, Any] = {"benchmark": "public-rss", "date": datetime.now(UTC).isoformat(),
                              "host": platform.node(), "n_frames": n_frames, "vehicle_d": vehicle_d,
                              "data": "SYNTHETIC smooth routes: long (n_frames x 16), wide "
                                      "(1,000 x vehicle_d)",
                              "settings_given": env, "load_average_before": list(psutil.getloadavg())}  # fmt: skip
    with ServerProcess(data, env={**env, "GRIDPLACE_GRPC_PORT": str(port)}) as srv:
        srv.wait_ready(300)
        assert srv.proc is not None
        target = f"127.0.0.1:{port}"
        _warm_up(srv.url, target, long, wide)
        time.sleep(1.0)
        with TreeRss(srv.proc.pid) as rss:
            baseline = rss.now()
            rss.peak = baseline
            start = time.monotonic()
            vehicles = load.fill_rest_vehicles(srv.url, "wide", wide,
                                               rest_vehicles or settings.max_rest_vehicles)  # fmt: skip
            after_vehicles = rss.now()
            streams = load.HeldStreams(target, "long", long, settings.max_streams).start()
            filled = streams.wait_filled(600)
            after_streams = rss.now()
            computing = min(THREADS, settings.max_public_requests)
            drives = load.Loops(srv.url, computing, load.drive_request("long", long, drive_frames)).start()
            batch = load.batch_request("wide", wide, settings.max_public_body_mb * MIB)
            batches = load.Loops(srv.url, max(1, settings.max_public_bodies_mb // settings.max_public_body_mb),
                                 batch).start()  # fmt: skip
            time.sleep(min(3.0, seconds / 2))  # the drives and batches in flight first
            slow = load.SlowBodies(srv.url, settings.max_public_requests)  # then whatever is left
            time.sleep(max(0.0, seconds - 3.0))
            slow_held, slow_refused = slow.tally()
            slow.close()
            drive_statuses, batch_statuses = drives.stop(), batches.stop()
            streams.close()
            took = time.monotonic() - start
        with httpx.Client(base_url=srv.url, timeout=60) as c:
            after = c.post("/v1/localize/batch", json={"map": "long", "descriptors": long[:2].tolist()})
            health = c.get("/healthz")
        report["load_average_after"] = list(psutil.getloadavg())
    peak = rss.peak - baseline
    report.update({
        "baseline_mib": baseline / MIB, "peak_mib": rss.peak / MIB, "peak_above_baseline_mib": peak / MIB,
        "after_rest_vehicles_mib": (after_vehicles - baseline) / MIB,
        "after_streams_mib": (after_streams - baseline) / MIB,
        "bound_mib": bound, "peak_over_bound": peak / MIB / bound["total"], "seconds": took,
        "load": {
            "rest_vehicles": dict(vehicles), "streams": settings.max_streams, "streams_filled": filled,
            "stream_frames": dict(streams.answers),
            "drives": {"frames": drive_frames, "states": load.WORST_STATES, **drive_statuses},
            "json_batches": {"body_bytes": len(batch["content"]), **batch_statuses},  # type: ignore[arg-type]
            "slow_bodies": {"held": slow_held, "refused": slow_refused},
        },
        "answered_after": {"batch": after.status_code, "healthz": health.status_code},
    })  # fmt: skip
    if out is not None:
        out.parent.mkdir(parents=True, exist_ok=True)
        write_atomic(out, json.dumps(report, indent=2))
    return report

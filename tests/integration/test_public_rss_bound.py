"""The memory bound for unauthenticated callers (docs/RELIABILITY.md), measured: the worst
public load at once against a real ``gridplace serve`` at small settings, its peak RSS above
the baseline (the whole process tree) against :func:`~service.bench.public_rss.rss_bound`.

The load is ``gridplace bench public-rss``'s (REST vehicles filling their store, every gRPC
stream with as many filtered vehicles as the server takes, drives with the dearest filter at
the work budget, JSON batches at the body limit, bodies that never end), on a SYNTHETIC map
of 4,000 frames (drives of 543 frames with the dearest filter's 130 states at a work budget of 300 M units, 6 at once)
and a wide one of 1,000 × 256."""

from __future__ import annotations

from pathlib import Path

import pytest

from service.bench.public_load import WORST_STATES
from service.bench.public_rss import rss_bound, run_public_rss_bench
from service.settings import Settings

pytestmark = pytest.mark.slow
N, D = 4000, 256
ENV = {"GRIDPLACE_MAX_PUBLIC_REQUESTS": "6", "GRIDPLACE_MAX_REQUEST_WORK": "300",
       "GRIDPLACE_MAX_PUBLIC_BODIES_MB": "8", "GRIDPLACE_MAX_PUBLIC_BODY_MB": "2",
       "GRIDPLACE_MAX_STREAMS": "4", "GRIDPLACE_MAX_STREAM_STATE_MB": "32",
       "GRIDPLACE_MAX_REST_VEHICLES": "400", "GRIDPLACE_REST_VEHICLE_STATE_MB": "4"}  # fmt: skip


def test_the_bound_is_every_term_of_the_settings() -> None:
    assert WORST_STATES == 130  # 2 × 64 speeds + a stopped state per direction
    s = Settings(max_public_requests=12, max_public_bodies_mb=8, max_streams=4, grpc_workers=4,
                 max_stream_state_mb=32, max_stream_frame_kb=1024, rest_vehicle_state_mb=4)  # fmt: skip
    bound = rss_bound(s, N)
    assert bound["stream_state"] == 32 and bound["stream_buffers"] == 4 * 5
    assert bound["rest_vehicles"] == 4 and bound["public_bodies_parsed"] == 12 * 8
    assert bound["requests_computing"] == pytest.approx((12 + 4 + 1) * (128 + 20 * WORST_STATES * N / 2**20))
    assert bound["total"] == pytest.approx(sum(v for k, v in bound.items() if k != "total"))
    more = rss_bound(s.model_copy(update={"max_public_requests": 100}), N)
    assert more["requests_computing"] == pytest.approx((40 + 4 + 1) * (128 + 20 * WORST_STATES * N / 2**20))  # 40 REST threads


def test_the_worst_public_load_stays_under_the_bound(tmp_path: Path) -> None:
    report = run_public_rss_bench(N, D, seconds=8, env=ENV, out=tmp_path / "public-rss.json")
    load = report["load"]
    # the load reached every limit it is meant to: the numbers below are the bound working
    assert load["streams_filled"] and load["stream_frames"].get("RESOURCE_EXHAUSTED", 0) > 0, load
    assert load["rest_vehicles"] == {"200": 400}, load
    assert load["drives"].get("200", 0) > 0 and load["json_batches"].get("200", 0) > 0, load
    refused = load["drives"].get("503", 0) + load["json_batches"].get("503", 0) + load["slow_bodies"]["refused"]
    assert refused > 0, load  # the public budget was full
    assert report["peak_above_baseline_mib"] < report["bound_mib"]["total"], report
    assert report["answered_after"] == {"batch": 200, "healthz": 200}
    assert (tmp_path / "public-rss.json").exists()

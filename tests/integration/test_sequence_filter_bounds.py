"""The sequence filter behind ``POST /v1/localize/sequence`` on a real ``gridplace serve``:
no scratch memory kept per thread whatever the speed grids, and filter options that used to
divide by zero or answer ``speed: null`` give a correct 200 or a 4xx naming the option.

Data is SYNTHETIC: a smooth random-process route (N = 20,000, d = 32), fitted with the ridge
preset in the test process and published before the server starts.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import httpx
import numpy as np
import pytest

from service.api.process import ServerProcess
from service.encoding import ModelParams, build_model
from service.encoding.synthetic import smooth_route
from service.registry import Registry

pytestmark = pytest.mark.slow
N, D = 20_000, 32
PARAMS = {"encoder_preset": "ridge", "trainer": "ridge", "n_patterns": "2"}


@pytest.fixture(scope="module")
def served(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[ServerProcess, np.ndarray]]:
    data_dir = tmp_path_factory.mktemp("sequence-bounds")
    route = smooth_route(N, D, query_noise=0.3, seed=2)  # SYNTHETIC
    model = build_model(ModelParams.parse(**PARAMS)).fit(route.reference)
    Registry(data_dir).publish("long", model, params=PARAMS, extractor=None, metrics={})
    with ServerProcess(data_dir, env={"GRIDPLACE_ADMIN_TOKEN": "t"}) as srv:
        srv.wait_ready(60)
        yield srv, route.query


def _rss_mb(srv: ServerProcess) -> float:
    assert srv.proc is not None
    for line in Path(f"/proc/{srv.proc.pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    raise AssertionError("no VmRSS")


def _drive(c: httpx.Client, Q: np.ndarray, **params: object) -> httpx.Response:
    query = {"map": "long", "d": D, **{k: str(v).lower() if isinstance(v, bool) else v
                                        for k, v in params.items()}}  # fmt: skip
    return c.post("/v1/localize/sequence", params=query, content=Q.astype("<f4").tobytes(),
                  headers={"Content-Type": "application/octet-stream"})  # fmt: skip


def test_varied_speed_grids_leave_no_scratch_behind(served: tuple[ServerProcess, np.ndarray]) -> None:
    """Tiny requests with many different speed grids from many threads: the server's memory
    afterwards is what it was, give or take the allocator (a per-thread workspace of 4 grid
    shapes × 2 arrays, as before, would hold ≈ 1,280·S·N bytes: gigabytes here)."""
    srv, Q = served
    with httpx.Client(base_url=srv.url, timeout=120) as c:
        assert _drive(c, Q[:2]).status_code == 200
        before = _rss_mb(srv)
        grids = [dict(reverse=True, min_speed=0.0, max_speed=float(m), speed_step=float(m) / 63)
                 for m in np.linspace(2, 50, 24)]  # fmt: skip

        def one(i: int) -> int:
            return _drive(c, Q[i % 100 : i % 100 + 2], **grids[i % len(grids)]).status_code

        with ThreadPoolExecutor(8) as pool:
            codes = list(pool.map(one, range(96)))
        after = _rss_mb(srv)
    assert codes == [200] * 96
    states = 2 * 64 + 1
    per_thread_workspace_mb = 4 * 2 * states * N * 4 / 2**20  # the old cache, one thread
    assert after - before < min(250.0, 8 * per_thread_workspace_mb), (before, after)


@pytest.mark.parametrize(
    "params",
    [dict(relocalization=1.0), dict(relocalization="1"), dict(relocalization=1e-45, min_speed=50, max_speed=50),
     dict(relocalization=1e-38, min_speed=50, max_speed=50, emission_scale=1000),
     dict(whole_route_budget=1), dict(window_frames=1_000_000, whole_route_budget=1),
     dict(window_frames=8, whole_route_budget=1_000_000_000)],
)  # fmt: skip
def test_degenerate_filters_answer_finite_estimates(
    served: tuple[ServerProcess, np.ndarray], params: dict[str, object]
) -> None:
    srv, Q = served
    with httpx.Client(base_url=srv.url, timeout=60) as c:
        r = _drive(c, Q[100:140], **params)
    assert r.status_code == 200, r.text
    body = r.json()
    assert len(body["index"]) == 40 and all(0 <= i < N for i in body["index"])
    assert all(isinstance(s, float) and math.isfinite(s) for s in body["speed"])
    assert all(0.0 <= p <= 1.0 for p in body["confidence"])


def test_an_emission_scale_beyond_its_bound_is_a_422_naming_it(
    served: tuple[ServerProcess, np.ndarray],
) -> None:
    srv, Q = served
    with httpx.Client(base_url=srv.url, timeout=60) as c:
        r = _drive(c, Q[:5], emission_scale=1e6)
    assert r.status_code in (400, 422) and "emission_scale" in r.text, r.text


@pytest.mark.parametrize("option", ["whole_route_budget=0", "window_frames=4"])
def test_a_tracker_budget_below_its_bound_is_a_422_naming_it(
    served: tuple[ServerProcess, np.ndarray], option: str
) -> None:
    srv, Q = served
    name, value = option.split("=")
    with httpx.Client(base_url=srv.url, timeout=60) as c:
        r = _drive(c, Q[:5], **{name: int(value)})
    assert r.status_code in (400, 422) and name in r.text, r.text

"""What appearance adapters hold: ``nbytes`` against tracemalloc, and a store of REST
vehicles against its byte budget in a real process's RSS."""

from __future__ import annotations

import gc
import json
import subprocess
import sys
import textwrap
import tracemalloc

import numpy as np
import pytest

from service.core.model_store import LoadedModel
from service.core.vehicle_adapters import VehicleAdapters
from service.core.vehicle_state import ENTRY_OVERHEAD_BYTES
from service.encoding.adaptation import AppearanceAdapter
from service.encoding.normalization import Normalizer


class _Model:
    """Just the route statistics a served model exposes."""

    def __init__(self, d: int) -> None:
        rng = np.random.default_rng(0)
        self.normalizer_ = Normalizer(rng.normal(size=d).astype(np.float32),
                                      rng.uniform(0.5, 2, size=d).astype(np.float32))  # fmt: skip


def _traced(make: object, n: int) -> float:
    """Bytes tracemalloc sees per object made by ``make()`` and kept."""
    gc.collect()
    tracemalloc.start()
    try:
        before = tracemalloc.get_traced_memory()[0]
        kept = [make() for _ in range(n)]  # type: ignore[operator]
        after = tracemalloc.get_traced_memory()[0]
    finally:
        tracemalloc.stop()
    assert len(kept) == n
    return (after - before) / n


@pytest.mark.parametrize("d", [32, 512, 2048])
def test_an_adapters_nbytes_is_what_it_holds(d: int) -> None:
    model = _Model(d)
    AppearanceAdapter.for_model(model)  # the route's statistics, shared, made once

    def make() -> AppearanceAdapter:
        a = AppearanceAdapter.for_model(model)
        a.transform(np.ones((2, d)))
        return a

    held = _traced(make, 500)
    assert abs(held - make().nbytes) <= 0.05 * held, (held, make().nbytes)


def test_a_vehicle_stores_count_covers_what_it_holds() -> None:
    d = 256
    loaded = LoadedModel(map="m", version=1, model=_Model(d), info=None, extractor_config=None)  # type: ignore[arg-type]
    store = VehicleAdapters(max_vehicles=10**6, max_bytes=1 << 40)
    row = np.ones((1, d))
    store.adapt(loaded, "warm-up", row)
    ids = iter(range(10**6))

    def add() -> None:
        store.adapt(loaded, f"vehicle-{next(ids):0120d}", row)  # ids of the longest allowed

    held = _traced(add, 2000)
    counted = store.nbytes / len(store)
    assert held <= counted <= 1.2 * held, (held, counted, ENTRY_OVERHEAD_BYTES)


RSS_SCRIPT = textwrap.dedent(
    """
    import json, numpy as np
    from pathlib import Path
    from service.core.model_store import LoadedModel
    from service.core.vehicle_adapters import VehicleAdapters
    from service.encoding.normalization import Normalizer

    def rss():
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) * 1024

    class Model:
        normalizer_ = Normalizer(np.zeros(%(d)d, np.float32), np.ones(%(d)d, np.float32))

    loaded = LoadedModel(map="m", version=1, model=Model(), info=None, extractor_config=None)
    store = VehicleAdapters(max_bytes=%(budget)d)
    rows = np.random.default_rng(0).normal(size=(64, %(d)d))
    store.adapt(loaded, "warm-up", rows[:1])
    before = rss()
    for v in range(%(vehicles)d):
        store.adapt(loaded, f"vehicle-{v}", rows[v %% 64 : v %% 64 + 1])
    print(json.dumps({"grown": rss() - before, "held": len(store), "counted": store.nbytes}))
    """
)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_rest_vehicles_stay_within_their_byte_budget_in_rss() -> None:
    """12,000 vehicles on a d = 2,048 map against the default 256 MiB budget (they would hold
    300 MB as float32, 600 MB as the float64 adapters did): the process grows by the budget,
    not more (24,000 grew it by 564 MB when an adapter was counted as half of what it held)."""
    budget = 256 * 2**20
    script = RSS_SCRIPT % {"d": 2048, "budget": budget, "vehicles": 12_000}
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    got = json.loads(out.stdout)
    assert got["counted"] <= budget and got["held"] < 12_000
    assert got["grown"] <= 1.1 * budget, got

"""A tiny run of ``gridplace bench conditions`` (SYNTHETIC: a second traversal under a
per-column gain and offset): every figure is there, and naming the condition helps."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from service.bench.conditions_bench import TUNING_FRAMES, run_conditions_bench
from service.encoding.synthetic import smooth_route


def test_conditions_bench_smoke(tmp_path: Path) -> None:
    route = smooth_route(240, 32, query_noise=1.5, seed=4)
    rng = np.random.default_rng(3)
    winter = route.query * rng.uniform(0.3, 3.0, 32) + rng.normal(0.0, 2.0, 32)
    np.save(tmp_path / "ref.npy", route.reference.astype(np.float32))
    np.save(tmp_path / "qry.npy", winter.astype(np.float32))
    out = tmp_path / "conditions.json"
    run_conditions_bench(tmp_path / "ref.npy", tmp_path / "qry.npy", out, half=120)
    result = json.loads(out.read_text())
    assert list(result["tuning"]["precision_by_frames"]) == [str(k) for k in TUNING_FRAMES]
    single = result["single_frames"]
    assert single["named"] > single["no condition"] and single["frames_inferred_winter"] > 50
    assert list(result["drives"]) == ["10", "25", "100", "120"]
    short = result["drives"]["10"]
    assert short["named"]["frames"] > short["no condition"]["frames"]
    assert short["inferred"]["drives_inferred_winter"] == 100.0
    assert "filtered" in short["named"] and "filtered" not in result["drives"]["120"]["named"]

"""A tiny run of ``gridplace bench scale`` (SYNTHETIC): every figure is there and sane.
Its steps run in this process here (``isolate=False``); the command spawns one per step."""

from __future__ import annotations

import json
from pathlib import Path

from service.bench.scale_bench import run_scale_bench


def test_scale_bench_smoke(tmp_path: Path) -> None:
    out, fig = tmp_path / "scale.json", tmp_path / "q.png"
    run_scale_bench([3000], d=16, frames_per_chunk=1500, region_length=500, noise=0.3,
                    n_queries=100, n_single=10, batch=100, exact_frames=2000, trainer="ridge",
                    out=out, work_dir=tmp_path, figure=fig, isolate=False)  # fmt: skip
    (point,) = json.loads(out.read_text())["points"]
    assert point["params"]["n_chunks"] == 2
    train, serve, exact = point["train"], point["serve"], point["exact_nn"]
    assert train["artifact_bytes"] > 0 and train["peak_rss_bytes"] > 0 and train["train_seconds"] > 0
    assert serve["agreement_with_reference"] == 1.0  # the fast path answers as the reference
    assert 0.0 <= serve["precision_at_5"] <= 1.0 and serve["load_seconds"] > 0
    assert serve["single"]["cpu_s"] > 0 and serve["batch"]["cpu_s"] > 0
    assert exact["extrapolated"] and exact["stored_bytes_at_N"] == exact["stored_bytes_measured"] * 1.5
    assert fig.stat().st_size > 0
    assert not list(tmp_path.glob("gridplace-scale-*"))  # the route files are gone

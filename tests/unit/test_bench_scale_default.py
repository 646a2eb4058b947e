"""A tiny run of the default preset's ``gridplace bench scale`` (SYNTHETIC): every figure is
there and sane. Its steps run in this process here (``isolate=False``)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from service.bench.scale_default import run_default_scale_bench


def test_default_scale_bench_smoke(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr("service.encoding.inverted_file.AUTO_MIN_FRAMES", 1000)  # ivf at 2,000
    out, fig = tmp_path / "scale.json", tmp_path / "q.png"
    run_default_scale_bench([2000], d=32, region_length=500, noise=0.3, n_queries=100,
                            n_single=5, batch=50, exact_frames=1000, out=out,
                            work_dir=tmp_path, figure=fig, isolate=False,
                            sweep_noises=(0.3, 2.0), also=("drive",))  # fmt: skip
    (point,) = json.loads(out.read_text())["points"]
    train, serve, exact = point["train"], point["serve"], point["exact_nn"]
    assert train["artifact_bytes"] > 0 and train["peak_rss_bytes"] > 0
    assert serve["inverted_file"]["nprobe"] <= serve["inverted_file"]["nlist"] and serve["load_seconds"] > 0
    for key in ("ivf", "flat"):
        assert 0.0 <= serve[key]["precision_at_5"] <= 1.0 and serve[key]["single"]["cpu_s"] > 0
    assert 0.5 <= serve["ivf_agrees_with_flat"] <= 1.0
    assert serve["sequence"]["filter_update"]["cpu_s"] > 0
    sweep = serve["nprobe_sweep"]
    assert sweep["default_nprobe"] in sweep["probes"] and set(sweep["noises"]) == {"0.3", "2.0"}
    widest = sweep["noises"]["2.0"][str(max(sweep["probes"]))]
    assert 0.0 <= widest["precision_at_5"] <= 1.0 and 0.0 < widest["agrees_with_flat"] <= 1.0
    assert all(0 < v["share_scanned"] <= 1 for v in sweep["latency"].values())
    drive = point["also"]["drive"]  # the drive preset on the same route: its code, no ivf
    assert drive["train"]["artifact_bytes"] < train["artifact_bytes"]
    assert drive["serve"]["inverted_file"] is None and "ivf" not in drive["serve"]
    assert drive["serve"]["flat"]["single"]["cpu_s"] > 0
    assert drive["serve"]["sequence"]["frame_scores"]["cpu_s"] > 0
    for kind in ("ivf_sq8", "hnsw"):
        faiss = point["faiss"][kind]
        assert faiss["index_bytes"] > 0 and 0.0 <= faiss["precision_at_5"] <= 1.0
        assert set(faiss["precision_at_5_by_noise"]) == {"0.3", "2.0"}
    assert exact["extrapolated"] and exact["stored_bytes_at_N"] == exact["stored_bytes_measured"] * 2
    assert fig.stat().st_size > 0
    assert not list(tmp_path.glob("gridplace-scale-*"))

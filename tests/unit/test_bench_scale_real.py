"""A tiny run of ``gridplace bench scale-real``: the inverted file against its flat scan, over
the whole route and over each half (the first to choose on, the second to report)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from service.bench.scale_real import run_scale_real_bench
from service.encoding.synthetic import smooth_route


def test_scale_real_bench_reports_both_halves(tmp_path: Path) -> None:
    route = smooth_route(600, 64, seed=7, query_noise=0.8)
    ref, qry, out = tmp_path / "ref.npy", tmp_path / "qry.npy", tmp_path / "real.json"
    np.save(ref, route.reference.astype(np.float32))
    np.save(qry, route.query.astype(np.float32))
    report = run_scale_real_bench(ref, qry, out, n_single=3, nlist=40)
    assert json.loads(out.read_text()) == report
    assert report["N"] == 600 and report["nlist"] == 40
    rows = {r["nprobe"]: r for r in report["ivf"]}
    assert sum(r["default"] for r in rows.values()) == 1 and 40 in rows and min(rows) < 40
    every = rows[40]  # every list probed: the flat scan's answers, on the route and each half
    assert every["agrees_with_flat"] == 1.0 and every["share_scanned"] == 1.0
    assert every["points_below_flat"] == 0.0
    for half in ("A", "B"):
        flat = report["flat"]["halves"][half]["precision_at_5"]
        assert every["halves"][half] == {"precision_at_5": flat, "points_below_flat": 0.0}
    for r in rows.values():
        mean = (r["halves"]["A"]["precision_at_5"] + r["halves"]["B"]["precision_at_5"]) / 2
        assert abs(mean - r["precision_at_5"]) < 1e-12  # two halves of 300 frames each
        assert 0 < r["share_scanned"] <= 1 and r["single"]["cpu_s"] > 0

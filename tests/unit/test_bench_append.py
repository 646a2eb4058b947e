"""A tiny run of ``gridplace bench append`` (SYNTHETIC), unchunked and chunked: every map's
figures are there, and the appends take a fraction of the from-scratch time."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from service.bench.append_bench import run_append_bench
from service.encoding.synthetic import smooth_route


@pytest.mark.parametrize(("chunks", "maps"), [
    (1, ["unappended", "appended, front-end fixed", "appended", "from scratch"]),
    (2, ["unappended", "appended, front-end fixed", "from scratch"]),
])  # fmt: skip
def test_append_bench_smoke(tmp_path: Path, chunks: int, maps: list[str]) -> None:
    route = smooth_route(240, 32, query_noise=0.5, seed=4)
    np.save(tmp_path / "ref.npy", route.reference.astype(np.float32))
    np.save(tmp_path / "qry.npy", route.query.astype(np.float32))
    out = tmp_path / "append.json"
    run_append_bench(tmp_path / "ref.npy", tmp_path / "qry.npy", out, half=120, n_chunks=chunks)
    result = json.loads(out.read_text())
    assert result["n_chunks"] == chunks and list(result["maps"]) == maps
    for row in result["maps"].values():
        assert 0 <= row["as_sent"] <= 100 and 0 <= row["adapted"] <= 100 and row["seconds"] >= 0
    assert result["maps"]["from scratch"]["of_scratch_time"] == 1

"""Experiment 4: chunking at scale — a route of ≥ 89,000 frames split into chunks.

No real route of that length is available here, so the route is SYNTHETIC
(``smooth_route``: smooth random process along the route plus a slowly varying regional
component, queries = frames plus noise); every output of this experiment says so. A chunked gridplace model (chunk classifier + one phase
encoder per chunk) is trained on all frames and scored on an evenly spaced subset of the
queries (and of the reference frames themselves, "identical") at several frame tolerances,
beside a single unchunked encoder on the same route.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import numpy as np

from service.encoding import ChunkedPlaceEncoder, PhaseEncoder
from service.harness.config import BenchConfig
from service.harness.datasets import synthetic_dataset
from service.harness.measure import localize_timed, precisions
from service.harness.methods import Recognizer


def _score(
    model: Recognizer,
    conditions: dict[str, np.ndarray],
    truth: np.ndarray,
    bounds: np.ndarray | None,
    cfg: BenchConfig,
) -> dict[str, Any]:
    """Precision per tolerance (and chunk accuracy) on each query condition, and storage."""
    fp = model.footprint().to_dict()
    out: dict[str, Any] = {"paper_bytes": fp["paper_bytes"], "actual_bytes": fp["actual_bytes"]}
    for name, Q in conditions.items():
        loc, seconds = localize_timed(model, Q)
        res: dict[str, Any] = {
            "precision": precisions(loc.index, truth, cfg.chunk_tolerances),
            "query_us_per_descriptor": 1e6 * seconds / Q.shape[0],
        }
        if bounds is not None:
            true_chunk = np.searchsorted(bounds, truth, side="right") - 1
            res["chunk_accuracy"] = float(np.mean(loc.chunk == true_chunk))
        out[name] = res
    return out


def run_chunking(cfg: BenchConfig, progress: Callable[[str], None]) -> dict[str, Any]:
    progress(f"chunking: generating a SYNTHETIC route of {cfg.chunk_n_frames} frames")
    ds = synthetic_dataset(cfg.chunk_n_frames, cfg.chunk_n_features,
                           query_noise=cfg.chunk_query_noise,
                           region_length=cfg.chunk_region_length, seed=cfg.seed)  # fmt: skip
    n = ds.n_frames
    n_q = n if cfg.chunk_n_queries is None else min(n, cfg.chunk_n_queries)
    rows = np.unique(np.linspace(0, n - 1, n_q).astype(np.int64))
    conditions = {"identical": ds.reference[rows], "noisy": ds.query[rows]}
    truth = ds.ground_truth[rows]
    common = {"n_patterns": cfg.chunk_k, "rho": cfg.chunk_rho, "trainer": cfg.trainer,
              "dtype": cfg.dtype, "random_state": cfg.seed}  # fmt: skip
    models: dict[str, dict[str, Any]] = {}

    progress(f"chunking: training {cfg.chunk_n_chunks} chunks on N={n}")
    chunked = ChunkedPlaceEncoder(n_chunks=cfg.chunk_n_chunks, **common)  # type: ignore[arg-type]
    start = time.perf_counter()
    chunked.fit(ds.reference)
    train_s = time.perf_counter() - start
    progress(f"chunking: querying {rows.size} queries per condition")
    models["chunked"] = {
        "params": {**common, "n_chunks": cfg.chunk_n_chunks, "top_chunks": chunked.top_chunks},
        "train_seconds": train_s,
        "chunk_sizes": np.diff(chunked.chunk_bounds_).tolist(),
        **_score(chunked, conditions, truth, chunked.chunk_bounds_, cfg),
    }
    if cfg.chunk_compare_unchunked:
        progress(f"chunking: training one unchunked encoder on N={n}")
        single = PhaseEncoder(**common)  # type: ignore[arg-type]
        start = time.perf_counter()
        single.fit(ds.reference)
        train_s = time.perf_counter() - start
        models["unchunked"] = {
            "params": {**common, "periods": list(single.periods_)},
            "train_seconds": train_s,
            **_score(single, conditions, truth, None, cfg),
        }
    return {
        "dataset": ds.describe(),
        "n_queries_scored": int(rows.size),
        "query_selection": "evenly spaced" if rows.size < n else "all",
        "conditions": list(conditions),
        "tolerances": list(cfg.chunk_tolerances),
        "models": models,
    }

"""Appending a traversal against retraining: Nordland's summer map, winter half A appended.

Descriptors: a frame-aligned pair of ``.npy`` files (summer reference, winter queries; the
default CNN's). Maps, all with the default parameters (``robust``):

- **unappended**: trained on summer only;
- **appended**: the summer map after ``partial_fit`` of winter half A (frames 0–1,787 at their
  places), the front-end fixed (``whiten=False``) and with condition whitening (the default);
- **from scratch**: ``fit`` on summer and winter half A together (the refit: every row again,
  the front-end refitted).

Each is tested on winter half B (frames 1,788–3,575, never appended), single frames within
±5 frames, as sent and adapted (each drive standardised by its running statistics, as
streams serve them). Training and appending times are wall-clock seconds of one run, the
ratio taken in that run.

    gridplace bench append --ref REF.npy --qry QRY.npy --out docs/benchmarks/append.json

With ``--chunks C`` the maps are chunked (C chunks), appended with the front-end fixed (the
chunks share one projection: no condition whitening).
"""

from __future__ import annotations

import copy
import json
import time
from pathlib import Path
from typing import Any

import numpy as np

from service.encoding import ModelParams, build_model
from service.encoding.adaptation import adapt_drive
from service.encoding.base import precision_at
from service.harness.context import run_context

HALF_B = 1788  # the first frame of the test half
TOLERANCE = 5


def _precision(model: Any, B: np.ndarray, truth: np.ndarray) -> dict[str, float]:
    sent = precision_at(model.localize(B).index, truth, TOLERANCE)
    adapted = precision_at(model.localize(adapt_drive(model, B)).index, truth, TOLERANCE)
    return {"as_sent": round(100 * sent, 2), "adapted": round(100 * adapted, 2)}


def _timed(fn: Any) -> tuple[Any, float]:
    start = time.perf_counter()
    out = fn()
    return out, time.perf_counter() - start


def run_append_bench(ref_path: Path, qry_path: Path, out: Path, half: int = HALF_B,
                     n_chunks: int = 1) -> dict[str, Any]:  # fmt: skip
    """Measure the maps of the module docstring, print a table and write JSON to ``out``
    (``n_chunks`` > 1: chunked maps, which append without whitening)."""
    params = ModelParams.parse(n_chunks=n_chunks) if n_chunks > 1 else ModelParams()
    R = np.asarray(np.load(ref_path, mmap_mode="r"), np.float64)
    Q = np.asarray(np.load(qry_path, mmap_mode="r"), np.float64)
    if R.shape != Q.shape or not 0 < half < R.shape[0]:
        raise ValueError(f"need frame-aligned pairs longer than {half} frames: {R.shape}, {Q.shape}")
    A, B = Q[:half], Q[half:]
    truth = np.arange(half, Q.shape[0])
    base, t_base = _timed(lambda: build_model(params).fit(R))
    rows: dict[str, dict[str, Any]] = {
        "unappended": {"seconds": t_base, **_precision(base, B, truth)}
    }
    variants = (("appended, front-end fixed", False), ("appended", True))
    for name, whiten in variants[: 1 if n_chunks > 1 else 2]:
        model = copy.deepcopy(base)
        _, t = _timed(lambda m=model, w=whiten: m.partial_fit(A, places=np.arange(half), whiten=w))
        rows[name] = {"seconds": t, **_precision(model, B, truth)}
    scratch, t_scratch = _timed(lambda: build_model(params).fit(
        [R, A], places=[np.arange(R.shape[0]), np.arange(half)]))  # fmt: skip
    rows["from scratch"] = {"seconds": t_scratch, **_precision(scratch, B, truth)}
    for row in rows.values():
        row["of_scratch_time"] = round(row["seconds"] / t_scratch, 4)  # before rounding either
        row["seconds"] = round(row["seconds"], 3)
    result = {
        "benchmark": "append a traversal: summer map + winter half A, tested on winter half B",
        "context": run_context(),
        "descriptors": {"ref": str(ref_path), "qry": str(qry_path), "n": int(R.shape[0]),
                        "d": int(R.shape[1]), "appended_frames": [0, half - 1],
                        "test_frames": [half, int(Q.shape[0]) - 1]},  # fmt: skip
        "tolerance": TOLERANCE, "n_chunks": n_chunks,
        "maps": rows,
    }
    print(f"{'map':28} {'seconds':>8} {'of scratch':>10} {'as sent':>8} {'adapted':>8}")
    for name, row in rows.items():
        print(f"{name:28} {row['seconds']:8.2f} {row['of_scratch_time']:10.3f} "
              f"{row['as_sent']:8.2f} {row['adapted']:8.2f}")  # fmt: skip
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=1))
    return result

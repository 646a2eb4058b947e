"""Condition tags at query time on Nordland: a summer map, winter half A appended tagged
``season=winter``, queried with winter half B (never appended) as sent, with the condition
named, and with it inferred.

- **single frames**: each frame of half B as its own query; named: standardised by the
  winter statistics; inferred: by the condition its own frame is closest to (what a single
  query with ``condition=auto`` does), with the share of frames inferred as winter;
- **drives**: half B cut into drives of ``L`` frames (10, 25, 100, the whole half), each adapted from its first frame
  (appearance adaptation, as streams and sequences serve them) starting from the route's
  statistics (no condition), from the winter ones (named) or from the condition its first
  frames are closest to (inferred, the default of a version that records conditions); per
  frame, its own answer and the sequence filter's (default filter).

The inference window (``GRIDPLACE_CONDITION_FRAMES``) is chosen on half A alone: summer map
+ winter frames ``0…half/2−1`` appended, drives of the other quarter. Precision within ±5
frames; one run, seconds of the machine it ran on.

    gridplace bench conditions --ref REF.npy --qry QRY.npy --out docs/benchmarks/conditions.json
"""

from __future__ import annotations

import copy
import json
import time
from pathlib import Path
from typing import Any

import numpy as np

from service.encoding import ModelParams, build_model
from service.encoding.adaptation import AppearanceAdapter
from service.encoding.base import precision_at
from service.encoding.conditions import condition_set
from service.encoding.sequence import SequenceConfig, sequence_localize
from service.harness.context import run_context

HALF_B = 1788
TOLERANCE = 5
CONDITION = "season=winter"
DRIVE_LENGTHS = (10, 25, 100)  # and the whole test half as one drive
TUNING_FRAMES = (1, 2, 4, 8, 16, 32)
TUNING_LENGTH = 25


def _drives(model: Any, B: np.ndarray, start: np.ndarray, length: int, how: str | int,
            filtered: bool) -> dict[str, float]:  # fmt: skip
    """Precision of drives of ``length`` frames of ``B`` (places ``start + row``): per frame
    adapted from ``how`` (0: the route, a row of the condition set, ``"auto"``: inferred)."""
    cs = condition_set(model)
    raw, filt, inferred = [], [], []
    for s in range(0, B.shape[0] - length + 1, length):
        adapter = AppearanceAdapter.for_model(model)
        if how == "auto":
            adapter.start_from(cs, None)
        elif how:
            adapter.start_from(cs, int(how))
        X = adapter.transform(B[s : s + length])
        truth = start[s : s + length]
        raw.append(np.abs(model.localize(X).index - truth) <= TOLERANCE)
        if filtered:
            filt.append(np.abs(sequence_localize(model, X, SequenceConfig()).index - truth) <= TOLERANCE)
        inferred.append(adapter.condition_name == CONDITION)
    out = {"frames": round(100 * float(np.mean(np.concatenate(raw))), 2)}
    if filtered:
        out["filtered"] = round(100 * float(np.mean(np.concatenate(filt))), 2)
    if how == "auto":
        out["drives_inferred_winter"] = round(100 * float(np.mean(inferred)), 2)
    return out


def _tune(base: Any, A: np.ndarray, half: int) -> dict[str, Any]:
    """Raw precision of drives of the second quarter against the first appended, per window."""
    quarter = half // 2
    model = copy.deepcopy(base)
    model.partial_fit(A[:quarter], places=np.arange(quarter), condition=CONDITION)
    V, truth = A[quarter:half].astype(np.float32), np.arange(quarter, half)
    cs = condition_set(model)
    rows: dict[str, float] = {}
    for frames in TUNING_FRAMES:
        hits = []
        for s in range(0, V.shape[0] - TUNING_LENGTH + 1, TUNING_LENGTH):
            adapter = AppearanceAdapter.for_model(model).start_from(cs, None, frames)
            X = adapter.transform(V[s : s + TUNING_LENGTH])
            hits.append(np.abs(model.localize(X).index - truth[s : s + TUNING_LENGTH]) <= TOLERANCE)
        rows[str(frames)] = round(100 * float(np.mean(np.concatenate(hits))), 2)
    return {"appended": [0, quarter - 1], "validation": [quarter, half - 1],
            "drive_length": TUNING_LENGTH, "precision_by_frames": rows}  # fmt: skip


def run_conditions_bench(ref_path: Path, qry_path: Path, out: Path, half: int = HALF_B) -> dict[str, Any]:
    """Measure what the module docstring says, print the tables and write JSON to ``out``."""
    R = np.asarray(np.load(ref_path, mmap_mode="r"), np.float64)
    Q = np.asarray(np.load(qry_path, mmap_mode="r"), np.float64)
    if R.shape != Q.shape or not 0 < half < R.shape[0]:
        raise ValueError(f"need frame-aligned pairs longer than {half} frames: {R.shape}, {Q.shape}")
    A, B = Q[:half], Q[half:].astype(np.float32)
    truth = np.arange(half, Q.shape[0])
    start = time.perf_counter()
    base = build_model(ModelParams()).fit(R)
    fit_s = time.perf_counter() - start
    tuning = _tune(base, A, half)
    model = copy.deepcopy(base)
    model.partial_fit(A, places=np.arange(half), condition=CONDITION)
    cs = condition_set(model)
    assert cs is not None
    front = cs.mean[0], np.sqrt(cs.var[0])
    ll = cs.log_likelihood(B)
    own = np.argmax(ll, axis=1)
    per_frame = np.concatenate([cs.standardise(int(c), B[i : i + 1], *front) for i, c in enumerate(own)])
    single = {
        "no condition": round(100 * precision_at(model.localize(B).index, truth, TOLERANCE), 2),
        "named": round(100 * precision_at(model.localize(cs.standardise(1, B, *front)).index,
                                          truth, TOLERANCE), 2),  # fmt: skip
        "inferred per frame": round(100 * precision_at(model.localize(per_frame).index, truth,
                                                       TOLERANCE), 2),  # fmt: skip
        "frames_inferred_winter": round(100 * float(np.mean(own == 1)), 2),
    }
    drives: dict[str, dict[str, Any]] = {}
    for length in [*(n for n in DRIVE_LENGTHS if n < B.shape[0]), B.shape[0]]:
        filtered = length < B.shape[0]
        drives[str(length)] = {name: _drives(model, B, truth, length, how, filtered)
                               for name, how in (("no condition", 0), ("named", 1),
                                                 ("inferred", "auto"))}  # fmt: skip
    result = {
        "benchmark": "condition tags at query time: summer map + winter half A appended "
                     f"({CONDITION}), winter half B as sent, named, inferred",
        "context": run_context(),
        "descriptors": {"ref": str(ref_path), "qry": str(qry_path), "n": int(R.shape[0]),
                        "d": int(R.shape[1]), "appended_frames": [0, half - 1],
                        "test_frames": [half, int(Q.shape[0]) - 1]},  # fmt: skip
        "tolerance": TOLERANCE, "fit_seconds": round(fit_s, 2), "tuning": tuning,
        "single_frames": single, "drives": drives,
    }  # fmt: skip
    print("inference window, raw precision of 25-frame drives on half A's validation quarter:")
    print("  " + "  ".join(f"{k}: {v:.2f}" for k, v in tuning["precision_by_frames"].items()))
    print("single frames: " + ", ".join(f"{k} {v:.2f}" for k, v in single.items()))
    print(f"{'drive frames':>12} {'condition':>14} {'per frame':>10} {'filtered':>9}")
    for length, rows in drives.items():
        for name, row in rows.items():
            print(f"{length:>12} {name:>14} {row['frames']:10.2f} {row.get('filtered', float('nan')):9.2f}")
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=1))
    return result

"""Sequence-filter benchmark: per-frame cost beside the SeqSLAM window filter, and sequence
precision on Nordland (exact NN and gridplace on the same descriptors), in one run.

* Cost: random frame scores on routes of ``N`` frames (the filters' work does not depend on
  the scores' values); microseconds per update (CPU and wall) of the recursive (HMM) filter
  and of the former SeqSLAM window filter (window 10, speeds 0…2 by 0.25).
* Precision, with the session's validation split: the route is frames ``[0, 3576)``; half
  **A** = ``[0, 1788)`` tunes, half **B** = ``[1788, 3576)`` and the whole route report. A
  method is fitted on the summer frames of a split and its frame scores are computed for the
  winter frames. Tuning drives on A are the winter traversal driven at different speeds:
  ``speed_1`` (the traversal as recorded), ``speed_0.7``, ``speed_1.5``, a smoothly
  ``varying`` speed in [0.6, 1.8], a ``kidnap`` (after a third of the drive the vehicle is
  moved 500 frames ahead) and ``stops`` (it stands still for 40, later 80 frames). The
  configuration with the best mean precision at ±5 frames over every method and drive wins;
  B and the whole route are then reported at speed 1 without re-tuning.
"""

from __future__ import annotations

import itertools
import json
import os
import platform
import time
from dataclasses import asdict
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np
from rich.console import Console
from rich.table import Table

from service.bench.data import nordland
from service.bench.seqslam_reference import SeqSLAMConfig, SeqSLAMFilter, seqslam_sequence
from service.encoding import ExactNN, ModelParams, build_model
from service.encoding.base import PlaceRecognizer, precision_at
from service.encoding.sequence import SequenceConfig, SequenceFilter, SequenceTrack, filter_sequence

console = Console()
SPLITS = {"A": (0, 1788), "B": (1788, 3576), "all": (0, 3576)}
TOLERANCES = (0, 2, 5, 10)
OLD_FILTER = SeqSLAMConfig(window=10)
Candidate = SequenceConfig | SeqSLAMConfig
GRIDS: dict[str, dict[str, tuple[Any, ...]]] = {
    "small": {
        "emission_scale": (0.05, 0.1, 0.2, 0.3),
        "speed_change": (0.003, 0.01, 0.03),
        "relocalization": (1e-4, 1e-3),
        "stop_probability": (0.0, 0.01),
    },
    "tiny": {
        "emission_scale": (0.1,),
        "speed_change": (0.01,),
        "relocalization": (1e-4,),
        "stop_probability": (0.0,),
    },
}
SEQSLAM_WINDOWS = {"small": (5, 10, 20), "tiny": (10,)}


# -- cost --------------------------------------------------------------------------------------
def _us_per_update(filt: Any, rows: np.ndarray, repeats: int) -> dict[str, float]:
    """Wall and CPU microseconds per update (CPU time is what a busy machine cannot inflate)."""
    filt.update(rows[0])
    wall, cpu = time.perf_counter(), time.process_time()
    for k in range(repeats):
        filt.update(rows[k % rows.shape[0]])
    return {
        "wall_us": 1e6 * (time.perf_counter() - wall) / repeats,
        "cpu_us": 1e6 * (time.process_time() - cpu) / repeats,
    }


def filter_cost(sizes: list[int], repeats: int) -> dict[str, Any]:
    """Microseconds per frame of the HMM (default) and the SeqSLAM window filter, per ``N``."""
    out: dict[str, Any] = {}
    for n in sizes:
        rows = np.random.default_rng(n).normal(size=(8, n))
        old_repeats = max(3, repeats // 10)
        hmm = SequenceFilter(n)
        new = _us_per_update(hmm, rows, repeats)
        old = _us_per_update(SeqSLAMFilter(n, OLD_FILTER), rows, old_repeats)
        out[str(n)] = {
            "hmm": new,
            "seqslam": old,
            "speedup_cpu": old["cpu_us"] / new["cpu_us"],
            "speedup_wall": old["wall_us"] / new["wall_us"],
            "hmm_state_bytes": hmm.nbytes,
            "hmm_speeds": int(hmm.speeds.size),
            "repeats": {"hmm": repeats, "seqslam": old_repeats},
        }
    return out


# -- drives and precision -------------------------------------------------------------------
def _stops(n: int) -> list[tuple[int, int]]:
    """Segments of the ``stops`` drive: driving at speed 1, stopping 40 then 80 frames."""
    a, b = int(0.25 * n), int(0.55 * n)
    return [(0, a), (a, a + 40), (a, b), (b, b + 80), (b, n)]


def validation_drives(n: int, seed: int = 0) -> dict[str, np.ndarray]:
    """Frame positions of the tuning drives over a traversal of ``n`` frames (see module doc)."""
    rng = np.random.default_rng(seed)
    t = np.arange(3 * n)
    wave = sum(
        np.sin(2 * np.pi * t / rng.uniform(150, 600) + rng.uniform(0, 2 * np.pi)) for _ in range(3)
    )
    varying = np.cumsum(1.2 + 0.6 * wave / np.abs(wave).max())
    jump, gap = n // 3, min(500, n // 3)  # moved ``gap`` frames ahead after a third of the drive
    drives = {
        "speed_1": np.arange(n, dtype=float),
        "speed_0.7": np.arange(0, n - 1, 0.7),
        "speed_1.5": np.arange(0, n - 1, 1.5),
        "varying": varying[varying < n - 1],
        "kidnap": np.concatenate([np.arange(jump), np.arange(jump + gap, n)]).astype(float),
        "stops": np.concatenate(
            [
                np.arange(a, b) if k % 2 == 0 else np.full(b - a, a)
                for k, (a, b) in enumerate(_stops(n))
            ]
        ).astype(float),
    }
    return {k: np.rint(v).astype(np.int64) for k, v in drives.items()}


def _precisions(pred: np.ndarray, truth: np.ndarray) -> dict[str, float]:
    return {str(t): precision_at(pred, truth, t) for t in TOLERANCES}


def _methods(params: ModelParams) -> dict[str, PlaceRecognizer]:
    return {"exact_nn": ExactNN(), "gridplace": build_model(params)}


def _scores(
    split: str, ref: np.ndarray, qry: np.ndarray, params: ModelParams
) -> dict[str, dict[str, Any]]:
    lo, hi = SPLITS[split]
    out = {}
    for name, model in _methods(params).items():
        start = time.perf_counter()
        model.fit(ref[lo:hi])
        fit_s = time.perf_counter() - start
        out[name] = {
            "scores": model.frame_log_scores(qry[lo:hi]),
            "fit_seconds": fit_s,
            "footprint_bytes": model.footprint().actual_bytes,
        }
    return out


def _candidates(grid: str) -> list[Candidate]:
    g = GRIDS[grid]
    hmm: list[Candidate] = [
        SequenceConfig(**dict(zip(g, values, strict=True)))
        for values in itertools.product(*g.values())
    ]
    return hmm + [SeqSLAMConfig(window=w) for w in SEQSLAM_WINDOWS[grid]]


def _run(S: np.ndarray, config: Candidate) -> SequenceTrack:
    if isinstance(config, SeqSLAMConfig):
        return seqslam_sequence(S, config)
    return filter_sequence(S, config)


def _describe(config: Candidate) -> dict[str, Any]:
    if isinstance(config, SeqSLAMConfig):
        return {"method": "seqslam", **asdict(config)}
    return {"method": "hmm", **config.model_dump()}


def tune(scores: dict[str, np.ndarray], grid: str) -> dict[str, Any]:
    """Every candidate on every method × drive of split A; the best mean precision at ±5."""
    drives = validation_drives(next(iter(scores.values())).shape[0])
    rows = []
    for config in _candidates(grid):
        start = time.perf_counter()
        result: dict[str, float] = {}
        for (method, S), (drive, pos) in itertools.product(scores.items(), drives.items()):
            result[f"{method}/{drive}"] = precision_at(_run(S[pos], config).index, pos, 5)
        rows.append(
            {
                "config": _describe(config),
                "precision_at_5": result,
                "mean": float(np.mean(list(result.values()))),
                "seconds": time.perf_counter() - start,
            }
        )
        console.log(f"{_short(config)}: mean {rows[-1]['mean']:.3f}")
    best = max(rows, key=lambda r: r["mean"])
    best_hmm = max((r for r in rows if r["config"]["method"] == "hmm"), key=lambda r: r["mean"])
    best_old = max((r for r in rows if r["config"]["method"] == "seqslam"), key=lambda r: r["mean"])
    return {
        "split": "A",
        "objective": "mean precision@5 over methods x drives",
        "drives": {k: int(v.size) for k, v in drives.items()},
        "candidates": rows,
        "best": best["config"],
        "best_hmm": best_hmm["config"],
        "best_seqslam": best_old["config"],
    }


def _short(c: Candidate) -> str:
    if isinstance(c, SeqSLAMConfig):
        return f"seqslam window={c.window}"
    return (
        f"hmm scale={c.emission_scale} speed_change={c.speed_change} "
        f"reloc={c.relocalization} stop={c.stop_probability}"
    )


def _report(data: dict[str, dict[str, Any]], configs: dict[str, Candidate]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for method, d in data.items():
        S = d["scores"]
        truth = np.arange(S.shape[0])
        row: dict[str, Any] = {
            "single": _precisions(S.argmax(axis=1), truth),
            "footprint_bytes": d["footprint_bytes"],
            "fit_seconds": d["fit_seconds"],
        }
        for label, config in configs.items():
            start = time.perf_counter()
            pred = _run(S, config).index
            row[label] = _precisions(pred, truth)
            row[f"{label}_us_per_frame"] = 1e6 * (time.perf_counter() - start) / S.shape[0]
        out[method] = row
    return out


def run_sequence_bench(
    sizes: list[int], repeats: int, grid: str, with_nordland: bool, params: ModelParams, out: Path
) -> dict[str, Any]:
    report: dict[str, Any] = {
        "benchmark": "sequence",
        "date": datetime.now(UTC).isoformat(),
        "machine": {"cores": os.cpu_count(), "platform": platform.platform()},
        "default_filter": SequenceConfig().model_dump(),
        "old_filter": _describe(OLD_FILTER),
    }
    with console.status("timing the filters…"):
        report["filter_cost"] = filter_cost(sizes, repeats)
    route = nordland() if with_nordland else None
    if route is not None:
        report["data"] = {
            "label": route.label,
            "splits": SPLITS,
            "tolerances": list(TOLERANCES),
            "gridplace_params": params.model_dump(),
        }
        data = {}
        for s in SPLITS:
            with console.status(f"fitting exact NN and gridplace on summer {s}…"):
                data[s] = _scores(s, route.reference, route.query, params)
        tuning = tune({m: d["scores"] for m, d in data["A"].items()}, grid)
        report["tuning"] = tuning
        best_old = {k: v for k, v in tuning["best_seqslam"].items() if k != "method"}
        tuned = {k: v for k, v in tuning["best_hmm"].items() if k != "method"}
        configs: dict[str, Candidate] = {
            "sequence_default": SequenceConfig(),
            "sequence_tuned": SequenceConfig(**tuned),
            "seqslam": OLD_FILTER,
            "seqslam_tuned": SeqSLAMConfig(**best_old),
        }
        report["default_is_tuned"] = configs["sequence_default"] == configs["sequence_tuned"]
        report["precision"] = {s: _report(data[s], configs) for s in SPLITS}
    _print(report)
    out.write_text(json.dumps(report, indent=2))
    console.print(f"wrote {out}")
    return report


def _print(r: dict[str, Any]) -> None:
    t = Table(title="sequence filter: microseconds per frame, CPU (wall), same run")
    for col in ("N", "HMM (default)", "SeqSLAM window 10", "speed-up (CPU)"):
        t.add_column(col)
    for n, c in r["filter_cost"].items():
        h, o = c["hmm"], c["seqslam"]
        t.add_row(
            n,
            f"{h['cpu_us']:.0f} ({h['wall_us']:.0f})",
            f"{o['cpu_us']:.0f} ({o['wall_us']:.0f})",
            f"{c['speedup_cpu']:.1f}×",
        )
    console.print(t)
    if "precision" not in r:
        console.print("(Nordland not found: precision skipped)")
        return
    console.print(
        f"tuned on A: {r['tuning']['best_hmm']}; default == tuned: {r['default_is_tuned']}"
    )
    t = Table(title=f"precision@5, {r['data']['label']} (summer map → winter drive)")
    for col in (
        "split",
        "method",
        "single frame",
        "HMM (default)",
        "HMM (tuned on A)",
        "SeqSLAM w10",
        "SeqSLAM (tuned on A)",
    ):
        t.add_column(col)
    for split, methods in r["precision"].items():
        for method, row in methods.items():
            t.add_row(
                split,
                method,
                *(
                    f"{row[k]['5']:.3f}"
                    for k in (
                        "single",
                        "sequence_default",
                        "sequence_tuned",
                        "seqslam",
                        "seqslam_tuned",
                    )
                ),
            )
    console.print(t)

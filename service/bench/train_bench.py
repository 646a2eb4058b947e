"""Training benchmark: every trainer on the same data in one run, so ratios hold.

Two datasets: a large route (N=10,000, d=4096) as a SYNTHETIC smooth route (no real route
of that size and width exists here), and the real Nordland route (summer reference, winter
query, 3,576 × 2,048) with identical and cross-season queries.
"""

from __future__ import annotations

import json
import os
import platform
import time
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np
from rich.console import Console
from rich.progress import Progress
from rich.table import Table

from service.bench.data import nordland
from service.encoding import PhaseEncoder
from service.encoding.base import precision_at
from service.encoding.synthetic import smooth_route

console = Console()


def _measure(model: PhaseEncoder, X: np.ndarray, queries: dict[str, np.ndarray]) -> dict[str, Any]:
    start = time.perf_counter()
    model.fit(X)
    train_s = time.perf_counter() - start
    out: dict[str, Any] = {"train_seconds": train_s, "periods": list(model.periods_)}
    for name, Q in queries.items():
        start = time.perf_counter()
        pred = model.predict(Q)
        elapsed = time.perf_counter() - start
        truth = np.arange(Q.shape[0])
        out[f"{name}_precision_at_5"] = precision_at(pred, truth, 5)
        out[f"{name}_precision_at_0"] = precision_at(pred, truth, 0)
        out[f"{name}_query_us_per_descriptor"] = 1e6 * elapsed / Q.shape[0]
    fp = model.footprint()
    out["paper_bytes"] = fp.paper_bytes
    out["actual_bytes"] = fp.actual_bytes
    return out


def run_train_bench(
    n_frames: int, n_features: int, patterns: int, rho: float, trainers: list[str], out: Path
) -> dict[str, Any]:
    synth = smooth_route(n_frames, n_features, seed=0)
    datasets: list[tuple[str, np.ndarray, dict[str, np.ndarray]]] = [
        (f"synthetic-{n_frames}x{n_features}", synth.reference, {"noisy": synth.query}),
    ]
    real = nordland()
    if real is not None:
        datasets.append((real.name, real.reference, {"identical": real.reference,
                                                     "cross_season": real.query}))  # fmt: skip
    report: dict[str, Any] = {
        "benchmark": "train",
        "date": datetime.now(UTC).isoformat(),
        "machine": {"cores": os.cpu_count(), "platform": platform.platform()},
        "params": {"n_patterns": patterns, "rho": rho, "dtype": "float32", "decode": "joint",
                   "n_jobs": -1},  # fmt: skip
        "datasets": {},
    }
    if real is None:
        report["note"] = "real Nordland data not found; only the SYNTHETIC route was measured"
    with Progress(console=console, transient=True) as bar:
        task = bar.add_task("benchmarking", total=len(datasets) * len(trainers))
        for name, X, queries in datasets:
            rows = {}
            for trainer in trainers:
                bar.update(task, description=f"{name}: {trainer}")
                model = PhaseEncoder(n_patterns=patterns, rho=rho, trainer=trainer, n_jobs=-1)
                rows[trainer] = _measure(model, X, queries)
                report["datasets"][name] = {"N": X.shape[0], "d": X.shape[1], "trainers": rows}
                out.write_text(json.dumps(report, indent=2))  # partial results survive a stop
                bar.advance(task)
            label = synth.label if name.startswith("synthetic") else real.label  # type: ignore[union-attr]
            report["datasets"][name] = {"label": label, "N": X.shape[0], "d": X.shape[1],
                                        "trainers": rows}  # fmt: skip
    _print(report)
    out.write_text(json.dumps(report, indent=2))
    console.print(f"wrote {out}")
    return report


def _print(report: dict[str, Any]) -> None:
    for name, ds in report["datasets"].items():
        table = Table(title=f"{ds['label']} (N={ds['N']}, d={ds['d']})")
        rows = ds["trainers"]
        qkeys = [k for k in next(iter(rows.values())) if k.endswith("precision_at_5")]
        names = [f"P@5 {k.removesuffix('_precision_at_5')}" for k in qkeys]
        for col in ["trainer", "train s", *names, "µs/query", "paper B", "actual B"]:
            table.add_column(col)
        for trainer, r in rows.items():
            us = next(v for k, v in r.items() if k.endswith("query_us_per_descriptor"))
            table.add_row(trainer, f"{r['train_seconds']:.1f}", *(f"{r[k]:.3f}" for k in qkeys),
                          f"{us:.0f}", f"{r['paper_bytes']:.0f}", str(r["actual_bytes"]))  # fmt: skip
        console.print(table)

"""Experiment 3: precision vs the number of patterns k = 2…5 (periods τ ≈ N^(1/k)).

At the full route length and a fixed ρ, gridplace (balanced mixed-radix periods) and the Yu
et al. baseline (co-prime periods) for each k, on identical and cross-condition queries.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from service.harness.config import BenchConfig
from service.harness.datasets import Dataset
from service.harness.measure import evaluate_condition, fit_timed
from service.harness.methods import MethodSpec


def run_patterns(ds: Dataset, cfg: BenchConfig, progress: Callable[[str], None]) -> dict[str, Any]:
    X, Q, truth = ds.reference, ds.query, ds.ground_truth
    rows: list[dict[str, Any]] = []
    for k in cfg.pattern_ks:
        if 2**k > ds.n_frames:
            continue
        for method, rho in (("gridplace", cfg.pattern_rho), ("yu", 1.0)):
            spec = MethodSpec(method, rho=rho, k=k, trainer=cfg.trainer, dtype=cfg.dtype)
            progress(f"patterns {spec.short()}")
            fitted = fit_timed(spec, X)
            ident, _ = evaluate_condition(fitted.model, X, np.arange(ds.n_frames), cfg.tolerances)
            cross, _ = evaluate_condition(fitted.model, Q, truth, cfg.tolerances)
            periods = getattr(getattr(fitted.model, "inner", fitted.model), "periods_", None)
            fp = fitted.footprint()
            rows.append({
                "method": method, "k": k, "periods": list(periods or []),
                "params": spec.params(), "identical": ident["precision"],
                "cross": cross["precision"], "paper_bytes": fp["paper_bytes"],
                "actual_bytes": fp["actual_bytes"], "train_seconds": fitted.train_seconds,
            })  # fmt: skip
    return {"N": ds.n_frames, "rows": rows, "cross_tolerance": cfg.cross_tolerance}

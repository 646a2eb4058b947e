"""Experiment 2 (paper Table II): training and query time vs N, per trainer, one run.

gridplace with each trainer and the Yu et al. baseline, at fixed (k, ρ), on central segments of the
route, all on the same machine in the same process so that the ratios hold. Fast trainers are
fitted ``timing_repeats`` times and the fastest fit counts (the machine may be shared). ``logreg`` and
``svm`` (LIBLINEAR) are minutes per fit on a few thousand frames, so the quick budget stops
them at ``slow_trainer_max_n``; the JSON records the sizes each one ran at.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import numpy as np

from service.harness.config import BenchConfig
from service.harness.datasets import Dataset
from service.harness.measure import fit_timed, localize_timed
from service.harness.methods import MethodSpec
from service.harness.powerlaw import fit_power_law
from service.harness.sizes import geometric_sizes


def single_query_us(model: Any, Q: np.ndarray, repeats: int) -> float:
    """Median latency of one-row ``localize`` calls, in microseconds."""
    rows = np.linspace(0, Q.shape[0] - 1, max(1, repeats)).astype(int)
    times = []
    with np.errstate(divide="ignore"):  # log(0) of a zero confidence is -inf, as intended
        for r in rows:
            start = time.perf_counter()
            model.localize(Q[r : r + 1])
            times.append(time.perf_counter() - start)
    return 1e6 * float(np.median(times))


def timing_runs(cfg: BenchConfig) -> list[MethodSpec]:
    specs = [MethodSpec("gridplace", rho=cfg.timing_rho, k=cfg.timing_k, trainer=t,
                        dtype=cfg.dtype) for t in cfg.timing_trainers]  # fmt: skip
    specs += [MethodSpec("yu", rho=1.0, k=cfg.timing_k, trainer=t, dtype=cfg.dtype)
              for t in cfg.timing_yu_trainers]  # fmt: skip
    return specs


def run_timing(ds: Dataset, cfg: BenchConfig, progress: Callable[[str], None]) -> dict[str, Any]:
    sizes = geometric_sizes(cfg.timing_n_min, ds.n_frames, cfg.timing_n_points)
    rows: list[dict[str, Any]] = []
    for n in sizes:
        X = ds.segment(n)[0]
        for spec in timing_runs(cfg):
            if spec.trainer in cfg.slow_trainers and n > cfg.slow_trainer_max_n:
                continue
            progress(f"timing N={n} {spec.method}/{spec.trainer}")
            repeats = 1 if spec.trainer in cfg.slow_trainers else max(1, cfg.timing_repeats)
            fitted = min((fit_timed(spec, X) for _ in range(repeats)),
                         key=lambda f: f.train_seconds)  # fmt: skip
            _, batch_s = min((localize_timed(fitted.model, X) for _ in range(repeats)),
                             key=lambda r: r[1])  # fmt: skip
            rows.append({
                "method": spec.method, "trainer": spec.trainer, "N": n,
                "params": spec.params(), "train_seconds": fitted.train_seconds,
                "repeats": repeats,
                "query_us_per_descriptor_batch": 1e6 * batch_s / n,
                "query_us_single": single_query_us(fitted.model, X, cfg.single_query_repeats),
                "paper_bytes": fitted.footprint()["paper_bytes"],
            })  # fmt: skip
    return {"sizes": sizes, "rows": rows, "fits": _fits(rows),
            "slow_trainers": list(cfg.slow_trainers), "slow_trainer_max_n": cfg.slow_trainer_max_n}  # fmt: skip


def _fits(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """Training-time exponent per (method, trainer): ``seconds = c·N^a``."""
    out: dict[str, Any] = {}
    for key in dict.fromkeys((r["method"], r["trainer"]) for r in rows):
        sel = [r for r in rows if (r["method"], r["trainer"]) == key]
        name = f"{key[0]}/{key[1]}"
        if len({r["N"] for r in sel}) >= 2 and all(r["train_seconds"] > 0 for r in sel):
            out[name] = fit_power_law([r["N"] for r in sel],
                                      [r["train_seconds"] for r in sel]).to_dict()  # fmt: skip
        else:
            out[name] = None
    return out

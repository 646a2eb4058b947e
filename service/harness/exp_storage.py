"""Experiment 1 (paper Fig. 7 / Table I): storage needed to reach a target precision vs N.

For every route length N (the central N frames of the route, see ``Dataset.segment``) and every method, each setting of the
shared (ρ, k) grid is trained once and scored on both conditions:

- identical: the queries are the reference frames themselves, precision at tolerance 0;
- cross-condition: the dataset's queries whose place lies in the segment, precision at
  ``cross_tolerance`` frames.

For each target the smallest storage (paper formula, ``paper_bytes``) of a setting that
reaches it is kept per (method, N), and per method both ``storage = c·N^a`` (the growth
rate) and the paper's own form ``storage in MB = N^a`` (no prefactor) are fitted.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from service.errors import InvalidParameterError
from service.harness.config import BenchConfig
from service.harness.datasets import Dataset
from service.harness.measure import evaluate_condition, fit_timed
from service.harness.methods import MethodSpec
from service.harness.powerlaw import fit_paper_form, fit_power_law
from service.harness.sizes import geometric_sizes

Progress = Callable[[str], None]


def storage_grid(cfg: BenchConfig, n_frames: int) -> list[MethodSpec]:
    """The same (ρ, k) search for every method (k only where the method has one)."""
    specs: list[MethodSpec] = []
    for method in cfg.storage_methods:
        ks: tuple[int | None, ...] = cfg.storage_ks if method in ("gridplace", "yu") else (None,)
        for k in ks:
            if k is not None and 2**k > n_frames:
                continue  # more patterns than the route can use
            for rho in cfg.storage_rhos:
                specs.append(MethodSpec(method, rho=rho, k=k, trainer=cfg.trainer, dtype=cfg.dtype))
    return specs


def conditions(targets: BenchConfig) -> list[dict[str, Any]]:
    out = [
        {"condition": "identical", "tolerance": 0, "target": t} for t in targets.identical_targets
    ]
    out += [{"condition": "cross", "tolerance": targets.cross_tolerance, "target": t}
            for t in targets.cross_targets]  # fmt: skip
    return out


def run_storage(ds: Dataset, cfg: BenchConfig, progress: Progress) -> dict[str, Any]:
    sizes = geometric_sizes(cfg.storage_n_min, ds.n_frames, cfg.storage_n_points)
    points: list[dict[str, Any]] = []
    for n in sizes:
        X, Q, truth = ds.segment(n)
        for spec in storage_grid(cfg, n):
            progress(f"storage N={n} {spec.short()}")
            try:
                fitted = fit_timed(spec, X)
            except InvalidParameterError as exc:  # e.g. a setting the method cannot take
                points.append({"method": spec.method, "N": n, "params": spec.params(),
                               "error": str(exc)})  # fmt: skip
                continue
            ident, _ = evaluate_condition(fitted.model, X, np.arange(n), cfg.tolerances)
            cross, _ = evaluate_condition(fitted.model, Q, truth, cfg.tolerances)
            fp = fitted.footprint()
            points.append({
                "method": spec.method, "N": n, "params": spec.params(),
                "paper_bytes": fp["paper_bytes"], "actual_bytes": fp["actual_bytes"],
                "train_seconds": fitted.train_seconds,
                "identical": ident["precision"], "cross": cross["precision"],
                "n_cross_queries": cross["n_queries"],
            })  # fmt: skip
    return {
        "sizes": sizes,
        "sub_routes": "central N frames of the route",
        "points": points,
        "targets": summarize(points, cfg),
    }


def summarize(points: list[dict[str, Any]], cfg: BenchConfig) -> list[dict[str, Any]]:
    """Per target: the cheapest setting reaching it per (method, N), and the power-law fit."""
    out = []
    methods = list(dict.fromkeys(p["method"] for p in points))
    for cond in conditions(cfg):
        per_method: dict[str, Any] = {}
        for method in methods:
            best_by_n: list[dict[str, Any]] = []
            for n in sorted({p["N"] for p in points if p["method"] == method}):
                ok = [
                    p for p in points
                    if p["method"] == method and p["N"] == n and "error" not in p
                    and p[cond["condition"]][str(cond["tolerance"])] >= cond["target"]
                ]  # fmt: skip
                if ok:
                    best = min(ok, key=lambda p: (p["paper_bytes"], p["actual_bytes"]))
                    best_by_n.append({
                        "N": n, "paper_bytes": best["paper_bytes"],
                        "actual_bytes": best["actual_bytes"], "params": best["params"],
                        "precision": best[cond["condition"]][str(cond["tolerance"])],
                    })  # fmt: skip
            per_method[method] = {"best": best_by_n, **_fits(best_by_n)}
        out.append({**cond, "methods": per_method})
    return out


def _fits(best: list[dict[str, Any]]) -> dict[str, Any]:
    if len(best) < 2:
        return {"fit_paper": None, "fit_actual": None, "fit_paper_form": None,
                "fit_note": f"target reached at {len(best)} size(s); a fit needs 2"}  # fmt: skip
    ns = [b["N"] for b in best]
    return {
        "fit_paper": fit_power_law(ns, [b["paper_bytes"] for b in best]).to_dict(),
        "fit_actual": fit_power_law(ns, [b["actual_bytes"] for b in best]).to_dict(),
        "fit_paper_form": fit_paper_form(ns, [b["paper_bytes"] for b in best]).to_dict(),
    }

"""Experiment 5: gridplace against what users would pick instead — retrieval.

Exact nearest neighbour, product quantisation (faiss, when installed) and gridplace on the
full route: storage bytes, training time, query latency (batch and single query), precision
within 0/1/5/10/25 frames on identical and cross-condition queries, and precision–recall
curves obtained by rejecting queries below a confidence threshold (gridplace: the joint
digit probability; NN and PQ: the ratio test ``1 − d₁/d₂``).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from service.encoding.pq import faiss_available
from service.errors import InvalidParameterError
from service.harness.config import BenchConfig
from service.harness.datasets import Dataset
from service.harness.exp_timing import single_query_us
from service.harness.measure import evaluate_condition, fit_timed
from service.harness.methods import MethodSpec

PR_POINTS = 200  # points kept per precision–recall curve


def pr_curve(confidence: np.ndarray, correct: np.ndarray) -> dict[str, Any]:
    """Precision and recall as the confidence threshold falls (accepting more queries).

    ``recall`` is the fraction of all queries accepted and correct; ``average_precision`` is
    the area under the curve (step-wise); ``recall_at_100_precision`` is the largest recall
    with no accepted mistake.
    """
    n = confidence.shape[0]
    if n == 0:
        return {"precision": [], "recall": [], "average_precision": 0.0,
                "recall_at_100_precision": 0.0}  # fmt: skip
    order = np.argsort(-np.asarray(confidence, dtype=np.float64), kind="stable")
    hits = np.cumsum(np.asarray(correct, dtype=np.float64)[order])
    precision = hits / np.arange(1, n + 1)
    recall = hits / n
    ap = float(np.sum(np.diff(np.concatenate([[0.0], recall])) * precision))
    perfect = precision >= 1.0 - 1e-12
    r100 = float(recall[perfect].max()) if perfect.any() else 0.0
    keep = np.unique(np.linspace(0, n - 1, min(n, PR_POINTS)).astype(int))
    return {"precision": precision[keep].tolist(), "recall": recall[keep].tolist(),
            "average_precision": ap, "recall_at_100_precision": r100}  # fmt: skip


def retrieval_specs(cfg: BenchConfig, n_features: int, n_frames: int) -> list[MethodSpec]:
    specs = [MethodSpec("gridplace", rho=rho, k=k, trainer=cfg.trainer, dtype=cfg.dtype)
             for k, rho in cfg.retrieval_gridplace]  # fmt: skip
    specs.append(MethodSpec("exact_nn", dtype=cfg.dtype))
    if faiss_available() and n_frames >= 256:
        specs += [MethodSpec("pq", extra={"n_subquantizers": m})
                  for m in cfg.retrieval_pq_m if n_features % m == 0]  # fmt: skip
    return specs


def run_retrieval(ds: Dataset, cfg: BenchConfig, progress: Callable[[str], None]) -> dict[str, Any]:
    X, Q, truth = ds.reference, ds.query, ds.ground_truth
    conds = {"identical": (X, np.arange(ds.n_frames), 0),
             "cross": (Q, truth, cfg.cross_tolerance)}  # fmt: skip
    rows: list[dict[str, Any]] = []
    for spec in retrieval_specs(cfg, ds.n_features, ds.n_frames):
        progress(f"retrieval {spec.short()}")
        try:
            fitted = fit_timed(spec, X)
        except InvalidParameterError as exc:
            rows.append({"method": spec.method, "params": spec.params(), "error": str(exc)})
            continue
        fp = fitted.footprint()
        row: dict[str, Any] = {
            "method": spec.method, "label": spec.short(), "params": spec.params(),
            "paper_bytes": fp["paper_bytes"], "actual_bytes": fp["actual_bytes"],
            "train_seconds": fitted.train_seconds,
            "query_us_single": single_query_us(fitted.model, Q, cfg.single_query_repeats),
        }  # fmt: skip
        for name, (queries, gt, tol) in conds.items():
            res, loc = evaluate_condition(fitted.model, queries, gt, cfg.retrieval_tolerances)
            correct = np.abs(loc.index - gt) <= tol
            row[name] = {**res, "pr_tolerance": tol, "pr": pr_curve(loc.confidence, correct)}
        rows.append(row)
    return {"N": ds.n_frames, "rows": rows, "faiss": faiss_available(),
            "tolerances": list(cfg.retrieval_tolerances)}  # fmt: skip

"""``gridplace bench quality``: how well every method generalises across conditions, on the
same descriptors in one run.

For each descriptor set (a dataset folder, and/or pre-extracted ``.npy`` pairs) and each
protocol of :mod:`service.bench.quality_protocols`, every method of
:mod:`service.harness.quality_methods` is fitted once per fold and measured on each drive:

* single frame: ``localize`` (what the service answers for one query), precision within
  ±0/±2/±5/±10 frames;
* sequence: the drive's ``frame_log_scores`` through a fresh HMM filter
  (:func:`service.encoding.sequence.filter_sequence`; its default parameters were tuned on
  half A of protocol (a) by ``gridplace bench sequence``), same tolerances;
* adapted: the same two on the drive's rows after appearance adaptation
  (:mod:`service.encoding.adaptation`; a fresh adapter per drive, fed the drive in order),
  with the model's route statistics where it keeps them and otherwise those of the fold's
  training rows — so every method is adapted from the same kind of statistics;
* storage: the paper's formula and the bytes the model really stores (``footprint()``).

Nothing here is tuned: methods run at their fixed settings (adaptation at its default
``alpha``, chosen on half A of protocol (a)), so A (validation) numbers are the ones any
choice may be based on and B (test) the ones to quote.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from service.bench.quality_protocols import PROTOCOL_LABELS, PROTOCOLS, Fold, folds_for
from service.encoding.adaptation import AdaptationConfig, AppearanceAdapter, route_statistics
from service.encoding.base import precision_at
from service.encoding.sequence import SequenceConfig, filter_sequence
from service.errors import GridplaceError, InvalidInputError
from service.harness.context import run_context, set_torch_threads
from service.harness.datasets import Dataset, load_dataset
from service.harness.quality_methods import QualityMethod, catalogue, fit_places
from service.npyfile import load_npy

TOLERANCES: tuple[int, ...] = (0, 2, 5, 10)
HEADLINE = 5  # the tolerance of the plot and the one-line readings
KINDS: tuple[str, ...] = ("single", "sequence", "single_adapted", "sequence_adapted")
TUNED_WHERE = {
    "sequence_filter": "defaults tuned on half A of protocol (a) (`gridplace bench sequence`)",
    "adaptation": "default alpha chosen on half A of protocol (a) (robust, CNN and pixels)",
    "methods": "fixed settings; any preset choice was made on half A (validation) only",
    "test": "half B (protocol a) and each fold's unseen half (protocol b) were never tuned on",
}
Progress = Callable[[str], None]


def descriptor_pair(reference: Path, query: Path, ground_truth: Path | None = None,
                    name: str | None = None) -> Dataset:  # fmt: skip
    """A dataset from two ``.npy`` descriptor files (float, used as stored)."""
    ref = load_npy(reference).astype(np.float32, copy=False)
    qry = load_npy(query).astype(np.float32, copy=False)
    if ref.ndim != 2 or qry.ndim != 2 or ref.shape[1] != qry.shape[1] or 0 in (*ref.shape, *qry.shape):
        raise InvalidInputError(f"{reference} {ref.shape} and {query} {qry.shape} must be (n, d) "
                                "with the same d, n ≥ 1 and d ≥ 1")  # fmt: skip
    if ground_truth is not None:
        truth = load_npy(ground_truth).astype(np.int64)
    elif qry.shape[0] <= ref.shape[0]:
        truth = np.arange(qry.shape[0], dtype=np.int64)
    else:
        raise InvalidInputError(
            f"{qry.shape[0]} queries, {ref.shape[0]} frames and no ground truth"
        )
    if truth.shape != (qry.shape[0],) or truth.min() < 0 or truth.max() >= ref.shape[0]:
        raise InvalidInputError("ground truth must give one reference index per query")
    label = name or reference.resolve().parent.name
    return Dataset(
        name=label, reference=ref, query=qry, ground_truth=truth,
        label=f"{label}: reference {ref.shape[0]} x query {qry.shape[0]}, d={ref.shape[1]}, "
              "descriptors used as stored",
        synthetic=False, preprocessing={"mode": "none", "reference_from": str(reference),
                                        "query_from": str(query)},
        source=str(reference.parent.resolve()),
    )  # fmt: skip


def load_sets(dataset: Path | None, pairs: list[tuple[Path, Path]], patch: int = 16,
              ground_truth: Path | None = None) -> list[Dataset]:  # fmt: skip
    """The dataset folder (pixels patch-normalised as ``gridplace extract --extractor
    patchnorm`` does) and every descriptor pair, in that order."""
    sets = [load_dataset(dataset, preprocess="auto", patch=patch)] if dataset is not None else []
    sets += [descriptor_pair(r, q, ground_truth) for r, q in pairs]
    if not sets:
        raise InvalidInputError("give a dataset folder and/or --reference/--query descriptor pairs")
    return sets


def _precisions(pred: np.ndarray, truth: np.ndarray) -> dict[str, float]:
    return {str(t): precision_at(pred, truth, t) for t in TOLERANCES}


def drive_adapter(model: Any, fold: Fold,
                  config: AdaptationConfig) -> tuple[AppearanceAdapter, str]:  # fmt: skip
    """The adapter of ``model``'s drives and where its statistics come from: the model's route
    statistics if it keeps them, else those of the fold's training rows (a baseline without a
    normaliser, or one wrapped for several traversals)."""
    if route_statistics(model) is not None:
        return AppearanceAdapter.for_model(model, config), "model"
    return AppearanceAdapter.for_reference(fold.train_rows, config), "training rows"


def measure_adapted(model: Any, adapter: AppearanceAdapter, drives: dict[str, np.ndarray],
                    query: np.ndarray, truth: np.ndarray,
                    config: SequenceConfig) -> tuple[dict[str, Any], float]:  # fmt: skip
    """Single frame and sequence precision of every drive adapted on its own (the adapter
    reset, then fed the drive's rows in order), and the seconds spent adapting."""
    out: dict[str, Any] = {}
    adapt_s = 0.0
    for name, drive in drives.items():
        adapter.reset()
        start = time.perf_counter()
        rows = adapter.transform(query[drive])
        adapt_s += time.perf_counter() - start
        track = filter_sequence(model.frame_log_scores(rows), config)
        out[name] = {"single_adapted": _precisions(model.localize(rows).index, truth[drive]),
                     "sequence_adapted": _precisions(track.index, truth[drive])}  # fmt: skip
    return out, adapt_s


def measure(method: QualityMethod, fold: Fold, query: np.ndarray, truth: np.ndarray,
            config: SequenceConfig,
            adaptation: AdaptationConfig | None = None) -> dict[str, Any]:  # fmt: skip
    """Fit ``method`` on ``fold`` and measure every drive of it: single frame and sequence,
    as given and adapted."""
    adaptation = adaptation or AdaptationConfig()
    start = time.perf_counter()
    model = fit_places(method.build(), fold.train_rows, fold.train_places)
    fit_s = time.perf_counter() - start
    fp = model.footprint()
    rows = np.unique(np.concatenate(list(fold.drives.values())))
    start = time.perf_counter()
    pred = model.localize(query[rows]).index
    query_s = time.perf_counter() - start
    at = {int(r): i for i, r in enumerate(rows)}
    scores = model.frame_log_scores(query[rows])
    drives: dict[str, Any] = {}
    seq_s = 0.0
    for name, drive in fold.drives.items():
        pos = np.fromiter((at[int(r)] for r in drive), dtype=np.int64, count=drive.size)
        start = time.perf_counter()
        track = filter_sequence(scores[pos], config)
        seq_s += time.perf_counter() - start
        drives[name] = {"n": int(drive.size), "single": _precisions(pred[pos], truth[drive]),
                        "sequence": _precisions(track.index, truth[drive])}  # fmt: skip
    adapter, statistics = drive_adapter(model, fold, adaptation)
    adapted, adapt_s = measure_adapted(model, adapter, fold.drives, query, truth, config)
    for name, figures in adapted.items():
        drives[name].update(figures)
    n_places = int(model.n_frames_)
    n_driven = max(1, sum(d.size for d in fold.drives.values()))
    return {
        "method": method.name, "family": method.family, "params": method.params,
        "fold": fold.name, "fit_seconds": fit_s,
        "query_us": 1e6 * query_s / max(1, rows.size),
        "sequence_us_per_frame": 1e6 * seq_s / n_driven,
        "adapt_us_per_frame": 1e6 * adapt_s / n_driven,
        "adaptation": {"statistics": statistics, "config": adaptation.model_dump()},
        "paper_bytes": fp.paper_bytes, "actual_bytes": fp.actual_bytes,
        "actual_bytes_per_place": fp.actual_bytes / n_places, "n_places": n_places,
        "footprint": fp.to_dict(), "drives": drives,
    }  # fmt: skip


def _pooled(drives: list[dict[str, Any]]) -> dict[str, Any]:
    """Drives as one (precision weighted by queries), for every kind all of them have."""
    n = sum(d["n"] for d in drives)
    out: dict[str, Any] = {"n": n}
    for kind in (k for k in KINDS if all(k in d for d in drives)):
        out[kind] = {t: sum(d[kind][t] * d["n"] for d in drives) / n for t in drives[0][kind]}
    return out


def pool_folds(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """One method's folds as one row: drives side by side, ``all`` = every fold's test rows
    pooled (precision weighted by queries), storage and times averaged over the folds."""
    first = rows[0]
    drives: dict[str, Any] = {}
    for r in rows:
        drives.update(r["drives"])
    if len(rows) > 1 and "all" not in drives:
        drives["all"] = _pooled(list(drives.values()))
    mean = {k: float(np.mean([r[k] for r in rows])) for k in
            ("fit_seconds", "query_us", "sequence_us_per_frame", "adapt_us_per_frame",
             "paper_bytes", "actual_bytes", "actual_bytes_per_place")
            if all(k in r for r in rows)}  # fmt: skip
    kept = ("method", "family", "params", "n_places", "footprint", "adaptation")
    return {**{k: first[k] for k in kept if k in first}, **mean,
            "folds": [r["fold"] for r in rows], "drives": drives}  # fmt: skip


def add_ratios(results: list[dict[str, Any]]) -> None:
    """``bytes_vs_exact_nn`` of every row: its actual bytes over exact NN's in the same block."""
    nn = next((r for r in results if r["method"] == "exact-nn"), None)
    for r in results:
        r["bytes_vs_exact_nn"] = r["actual_bytes"] / nn["actual_bytes"] if nn else None


def run_protocol(ds: Dataset, protocol: str, methods: list[QualityMethod], config: SequenceConfig,
                 progress: Progress,
                 adaptation: AdaptationConfig | None = None) -> dict[str, Any]:  # fmt: skip
    folds = folds_for(protocol, ds.reference, ds.query, ds.ground_truth)
    results, errors = [], []
    for method in methods:
        per_fold = []
        try:
            for fold in folds:
                progress(f"{ds.name} {protocol}: {method.name} ({fold.name})")
                per_fold.append(measure(method, fold, ds.query, ds.ground_truth, config,
                                        adaptation))  # fmt: skip
        except GridplaceError as exc:
            errors.append({"method": method.name, "family": method.family, "error": str(exc)})
            continue
        results.append(pool_folds(per_fold))
    add_ratios(results)
    return {"protocol": protocol, "label": PROTOCOL_LABELS[protocol],
            "folds": [{"name": f.name, "train_rows": int(f.train_rows.shape[0]),
                       "drives": {k: int(v.size) for k, v in f.drives.items()},
                       "tuned_on": f.tuned_on} for f in folds],
            "results": results, "errors": errors}  # fmt: skip


def run_quality_bench(
    sets: list[Dataset],
    protocols: tuple[str, ...],
    methods: str,
    config: SequenceConfig,
    out: Path,
    progress: Progress = lambda _m: None,
    yu_trainer: str = "ridge",
    argv: list[str] | None = None,
    adaptation: AdaptationConfig | None = None,
) -> dict[str, Any]:
    """Every protocol × method on every descriptor set; the report is written to ``out``."""
    adaptation = adaptation or AdaptationConfig()
    bad = [p for p in protocols if p not in PROTOCOLS]
    if bad:
        raise InvalidInputError(f"unknown protocol(s) {bad}; choose from {PROTOCOLS}")
    set_torch_threads(1)
    start = time.perf_counter()
    report: dict[str, Any] = {
        "benchmark": "quality", "context": run_context(argv), "tolerances": list(TOLERANCES),
        "headline_tolerance": HEADLINE, "sequence_filter": config.model_dump(),
        "adaptation": adaptation_summary(adaptation), "tuned_where": TUNED_WHERE, "sets": [],
    }  # fmt: skip
    for ds in sets:
        chosen = catalogue(ds.n_features, ds.n_frames, methods, yu_trainer)
        entry = {"dataset": ds.describe(), "protocols": {}}
        report["sets"].append(entry)
        for protocol in protocols:
            entry["protocols"][protocol] = run_protocol(ds, protocol, chosen, config, progress,
                                                        adaptation)  # fmt: skip
            _write(report, out, time.perf_counter() - start)  # a long run keeps what it measured
    _write(report, out, time.perf_counter() - start)
    return report


def adaptation_summary(config: AdaptationConfig) -> dict[str, Any]:
    """What the report's ``*_adapted`` figures are (each result says whose statistics)."""
    return {
        "config": config.model_dump(),
        "drives": "each drive adapted on its own, in drive order, by a fresh adapter",
        "statistics": "'model': the fitted model's route statistics (its normaliser); "
                      "'training rows': column statistics of the fold's training rows, for "
                      "models that keep none",
    }  # fmt: skip


def _write(report: dict[str, Any], out: Path, elapsed: float) -> None:
    report["elapsed_seconds"] = elapsed
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(out.name + ".tmp")
    tmp.write_text(json.dumps(report, indent=2, default=_json_default))
    tmp.replace(out)


def _json_default(o: Any) -> Any:
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    return str(o)


def _kept(row: dict[str, Any], keep: set[str] | None) -> bool:
    return keep is None or row["method"] in keep or row["family"] in keep


def merge_reports(reports: list[dict[str, Any]], methods: str = "all") -> dict[str, Any]:
    """Several runs as one report: per descriptor set (by name) and protocol, the methods of
    every run in order (a method measured twice keeps its later run; ``methods``, names or
    families comma-separated, keeps only those). Each run's context is kept under ``runs``."""
    keep = None if methods == "all" else {m.strip() for m in methods.split(",") if m.strip()}
    if not reports:
        raise InvalidInputError("nothing to merge")
    runs = [run for r in reports for run in r.get("runs", [r["context"]])]  # merged ones too
    merged: dict[str, Any] = {**reports[0], "sets": [], "runs": runs}
    adapted = [r["adaptation"] for r in reports if "adaptation" in r]
    if adapted:  # reports from before adaptation have none (their rows show no adapted figures)
        merged["adaptation"] = adapted[-1]
    by_name: dict[str, dict[str, Any]] = {}
    for rep in reports:
        for entry in rep["sets"]:
            name = entry["dataset"]["name"]
            if name not in by_name:
                by_name[name] = {"dataset": entry["dataset"], "protocols": {}}
                merged["sets"].append(by_name[name])
            protocols = by_name[name]["protocols"]
            for key, block in entry["protocols"].items():
                if key not in protocols:
                    protocols[key] = {**block, "results": [], "errors": []}
                into = protocols[key]
                fresh = {r["method"] for r in block["results"] + block["errors"]}
                into["results"] = [r for r in into["results"] if r["method"] not in fresh]
                into["errors"] = [e for e in into["errors"] if e["method"] not in fresh]
                into["results"] += [r for r in block["results"] if _kept(r, keep)]
                into["errors"] += [e for e in block["errors"] if _kept(e, keep)]
                add_ratios(into["results"])
    merged["elapsed_seconds"] = sum(r.get("elapsed_seconds", 0.0) for r in reports)
    return merged

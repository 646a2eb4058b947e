"""``gridplace bench drive``: localising moving vehicles, every method through the same filter.

Each method is fitted once on the reference traversal (the map is the whole route) and its
frame scores ``(T, N)`` are computed once for the query traversal — after appearance
adaptation (:mod:`service.encoding.adaptation`, the traversal fed in its recorded order, the
same adapted rows for every method; ``adapt=False`` turns it off). Every drive
(:mod:`service.bench.drive_protocols`) is cut from those rows and run through a fresh
:func:`service.encoding.sequence.filter_sequence` with the same configuration for every
method (the ``traffic`` drives' stops use near-identical copies of the query rows, scored once
as well: :func:`near_identical_copies`). Drives lie in one part of the route: half **A** (the
first half) tunes, half **B** and the whole route report. Odometry, when the filter takes it,
is SIMULATED from the ground truth (:func:`~service.bench.drive_protocols.noisy_odometry`).
"""

from __future__ import annotations

import inspect
import time
from collections.abc import Callable
from typing import Any

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from service.bench import drive_metrics as dm
from service.bench import drive_protocols as dp
from service.bench.drive_methods import DriveMethod, footprint
from service.encoding.adaptation import AdaptationConfig, AppearanceAdapter
from service.encoding.sequence import SequenceConfig, filter_sequence
from service.errors import InvalidParameterError
from service.harness.context import run_context
from service.harness.datasets import Dataset

PROTOCOLS: tuple[str, ...] = ("whole", "short", "speed", "traffic", "kidnap", "reverse")
REPORTED_SPLITS: tuple[str, ...] = ("B", "all")
ODOMETRY_MODEL = ("SIMULATED odometry from the ground-truth displacement d per frame: "
                  "d·(1 + s·e1) + s·e2, e1, e2 standard normal, s = the noise level "
                  "(multiplicative and additive, the additive part in reference frames); the "
                  "filter is told odometry_noise = s, odometry_floor = max(s, its own)")  # fmt: skip
_SCORE_BLOCK = 256
Progress = Callable[[str], None]


class DriveSettings(BaseModel):
    """Counts and seeds of the drives (every one configurable from the CLI)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    protocols: tuple[str, ...] = PROTOCOLS
    short_drives: int = Field(100, ge=1, le=100_000)
    short_length: int = Field(200, ge=1, le=100_000)
    speed_drives: int = Field(3, ge=1, le=10_000, description="drives per speed profile")
    speed_frames: int = Field(600, ge=10, le=1_000_000)
    traffic_drives: int = Field(9, ge=1, le=10_000, description="drives of the traffic generator")
    stop_noise: float = Field(
        0.03, ge=0.0, le=1.0,
        description="a stopped vehicle's near-identical frames (traffic): descriptor noise of "
        "this norm relative to the frame's",
    )
    kidnap_drives: int = Field(20, ge=1, le=10_000)
    kidnap_before: int = Field(150, ge=1, le=1_000_000)
    kidnap_after: int = Field(250, ge=1, le=1_000_000)
    min_jump: int = Field(200, ge=11, le=1_000_000)
    odometry_noise: tuple[float, ...] = (0.05, 0.1, 0.2)
    adapt: bool = True
    seed: int = Field(0, ge=0)


def splits(n: int) -> dict[str, tuple[int, int]]:
    return {"A": (0, n // 2), "B": (n // 2, n), "all": (0, n)}


def make_drives(lo: int, hi: int, truth: np.ndarray, s: DriveSettings,
                seed: int) -> dict[str, list[dp.Drive]]:  # fmt: skip
    """Every protocol's drives inside ``[lo, hi)``; a protocol that does not fit is left out."""
    out: dict[str, list[dp.Drive]] = {}
    make: dict[str, Callable[[], list[dp.Drive]]] = {
        "whole": lambda: dp.whole(lo, hi, truth),
        "short": lambda: dp.short(lo, hi, truth, s.short_drives, s.short_length, seed),
        "speed": lambda: dp.speed(lo, hi, truth, s.speed_drives, s.speed_frames, seed),
        "traffic": lambda: dp.traffic(lo, hi, truth, s.traffic_drives, s.speed_frames, seed),
        "kidnap": lambda: dp.kidnap(lo, hi, truth, s.kidnap_drives, s.kidnap_before,
                                    s.kidnap_after, s.min_jump, seed),  # fmt: skip
        "reverse": lambda: dp.reverse(lo, hi, truth),
    }
    for p in s.protocols:
        try:
            out[p] = make[p]()
        except InvalidParameterError:
            continue  # the part is too short for this protocol
    return out


def odometry_supported() -> bool:
    """Whether this build's filter takes per-frame odometry (``filter_sequence(…, odometry=)``)."""
    return "odometry" in inspect.signature(filter_sequence).parameters


def stated(config: SequenceConfig, level: float) -> SequenceConfig:
    """``config`` with the odometry noise the vehicle states (the simulated ``level``, as a
    fraction of the displacement and, at least the configured floor, in frames), where this
    build's filter has those parameters."""
    fields = type(config).model_fields
    update: dict[str, float] = {}
    if "odometry_noise" in fields:
        update["odometry_noise"] = level
    if "odometry_floor" in fields:
        update["odometry_floor"] = max(level, float(getattr(config, "odometry_floor")))
    return SequenceConfig.parse(**{**config.model_dump(), **update}) if update else config


def track(scores: np.ndarray, drive: dp.Drive, config: SequenceConfig,
          odometry: np.ndarray | None = None) -> np.ndarray:  # fmt: skip
    """The filtered estimates of one drive (its rows cut from the method's frame scores)."""
    rows = scores[drive.rows]
    if odometry is None:
        return filter_sequence(rows, config).index
    return filter_sequence(rows, config, odometry=odometry).index  # type: ignore[call-arg]


def evaluate(scores: np.ndarray, drives: dict[str, list[dp.Drive]], config: SequenceConfig,
             level: float | None, seed: int) -> dict[str, Any]:  # fmt: skip
    """Every protocol's figures for one filter configuration; ``level``: odometry noise
    (``None``: no odometry)."""
    out: dict[str, Any] = {}
    if level is not None:
        config = stated(config, level)
    for p, ds in drives.items():
        odo = [None if level is None else dp.noisy_odometry(d.motion, level, [seed, k, int(1e6 * level)])
               for k, d in enumerate(ds)]  # fmt: skip
        start = time.perf_counter()
        preds = [track(scores, d, config, o) for d, o in zip(ds, odo, strict=True)]
        frames = sum(len(d) for d in ds)
        truths = [d.truth for d in ds]
        m: dict[str, Any] = {"drives": len(ds), "frames": frames,
                             "precision": dm.precision(preds, truths),
                             "interval95": dm.precision_interval(preds, truths, seed=seed),
                             "us_per_frame": 1e6 * (time.perf_counter() - start) / frames}  # fmt: skip
        if p == "short":
            curve = dm.precision_after(preds, truths)
            m["curve"] = [round(float(c), 4) for c in curve]
            m["l90"] = dm.first_reaching(curve)
        elif p == "speed":
            by: dict[str, list[int]] = {}
            for k, d in enumerate(ds):
                by.setdefault(d.name.split("-")[1], []).append(k)
            m["by_profile"] = {g: dm.precision([preds[k] for k in ks], [truths[k] for k in ks])
                               for g, ks in by.items()}  # fmt: skip
        elif p == "kidnap":
            m["recovery"] = dm.recovery_summary(
                [dm.recovery(pr, d.truth, d.event) for pr, d in zip(preds, ds, strict=True)])
        elif p == "reverse":
            back = config.model_copy(update={"reverse": True})
            m["precision_reverse_filter"] = dm.precision(
                [track(scores, d, back, o) for d, o in zip(ds, odo, strict=True)], truths)
        out[p] = m
    return out


def evaluate_all(scores: np.ndarray, drives: dict[str, dict[str, list[dp.Drive]]],
                 config: SequenceConfig, s: DriveSettings) -> dict[str, Any]:  # fmt: skip
    """Every reported split, without odometry and at each noise level (or marked unavailable)."""
    out: dict[str, Any] = {}
    can = odometry_supported()
    for split in REPORTED_SPLITS:
        row: dict[str, Any] = {"none": evaluate(scores, drives[split], config, None, s.seed)}
        for level in s.odometry_noise:
            row[f"odometry_{level:g}"] = (evaluate(scores, drives[split], config, level, s.seed)
                                          if can else {"available": False})  # fmt: skip
        out[split] = row
    return out


def adapted_queries(ds: Dataset, adapt: bool) -> tuple[np.ndarray, dict[str, Any]]:
    """The query traversal as every method sees it: adapted in its recorded order from the
    reference's statistics, or as given."""
    if not adapt:
        return ds.query, {"applied": False}
    config = AdaptationConfig()
    start = time.perf_counter()
    rows = AppearanceAdapter.for_reference(ds.reference, config).transform(ds.query)
    return rows, {"applied": True, "config": config.model_dump(), "statistics": "reference",
                  "order": "the query traversal as recorded; drives are cut from it",
                  "seconds": time.perf_counter() - start}  # fmt: skip


def frame_scores(model: Any, queries: np.ndarray) -> np.ndarray:
    out = np.empty((queries.shape[0], int(model.n_frames_)), dtype=np.float32)
    for s in range(0, queries.shape[0], _SCORE_BLOCK):
        out[s : s + _SCORE_BLOCK] = model.frame_log_scores(queries[s : s + _SCORE_BLOCK])
    return out


def near_identical_copies(queries: np.ndarray, noise: float, seed: int) -> np.ndarray:
    """:data:`~service.bench.drive_protocols.COPIES` copies of every query row with Gaussian
    noise of norm ``noise`` × the row's (a stopped vehicle's camera), stacked after each other."""
    rng = np.random.default_rng([seed, 6])
    norms = np.linalg.norm(queries, axis=1, keepdims=True)
    out = []
    for _ in range(dp.COPIES):
        e = rng.standard_normal(queries.shape)
        e *= noise * norms / np.maximum(np.linalg.norm(e, axis=1, keepdims=True), 1e-30)
        out.append((queries + e).astype(queries.dtype))
    return np.concatenate(out)


def fit_method(m: DriveMethod, ds: Dataset, queries: np.ndarray,
               copies: np.ndarray | None = None) -> tuple[np.ndarray, dict[str, Any]]:  # fmt: skip
    """Fit ``m`` on the reference; its frame scores of every query row (then of the ``copies``
    rows, when given), and what it cost."""
    start = time.perf_counter()
    model = m.build().fit(ds.reference)
    fit_s = time.perf_counter() - start
    start = time.perf_counter()
    scores = frame_scores(model, queries)
    score_s = time.perf_counter() - start
    if copies is not None:
        scores = np.concatenate([scores, frame_scores(model, copies)])
    best = scores[: queries.shape[0]].argmax(axis=1)
    single = {name: float(dm.correct(best[lo:hi], ds.ground_truth[lo:hi]).mean())
              for name, (lo, hi) in splits(queries.shape[0]).items()}  # fmt: skip
    periods = getattr(model, "periods_", None)
    info = {"params": m.params, **footprint(model), "fit_seconds": fit_s,
            "periods": None if periods is None else [int(p) for p in periods],
            "score_us_per_query": 1e6 * score_s / queries.shape[0], "single": single}  # fmt: skip
    return scores, info


def run_drive_bench(ds: Dataset, chosen: list[DriveMethod], settings: DriveSettings,
                    config: SequenceConfig, tune: str = "off", grid: dict[str, Any] | None = None,
                    progress: Progress = lambda _m: None,
                    argv: list[str] | None = None) -> dict[str, Any]:  # fmt: skip
    """Fit, score and drive every method; tune on A if asked; the report (JSON-ready)."""
    from service.bench.drive_tuning import TUNE_MODES, tune_configs

    if tune not in TUNE_MODES:
        raise InvalidParameterError(f"--tune must be one of {', '.join(TUNE_MODES)}")
    start = time.perf_counter()
    context = run_context(argv)  # the code and command as they were when the run started
    n = ds.query.shape[0]
    drives = {name: make_drives(lo, hi, ds.ground_truth, settings, settings.seed + k)
              for k, (name, (lo, hi)) in enumerate(splits(n).items())}  # fmt: skip
    progress("adapting the query traversal…" if settings.adapt else "starting…")
    queries, adaptation = adapted_queries(ds, settings.adapt)
    copies = (near_identical_copies(queries, settings.stop_noise, settings.seed)
              if "traffic" in settings.protocols else None)  # fmt: skip
    scores: dict[str, np.ndarray] = {}
    methods: dict[str, Any] = {}
    for m in chosen:
        progress(f"{m.name}: fitting and scoring {n} queries against {ds.n_frames} frames…")
        scores[m.name], methods[m.name] = fit_method(m, ds, queries, copies)
    tuning = None
    if tune != "off":
        tuning = tune_configs(scores, drives["A"], config, tune, grid, settings.seed, progress)
    for m in chosen:
        progress(f"{m.name}: driving…")
        results = {"default": evaluate_all(scores[m.name], drives, config, settings)}
        if tuning is not None:
            chosen_cfg = SequenceConfig(**tuning["chosen"][m.name])
            results["tuned"] = evaluate_all(scores[m.name], drives, chosen_cfg, settings)
        methods[m.name]["results"] = results
        del scores[m.name]
    return {
        "benchmark": "drive", "context": context, "data": ds.describe(),
        "n_frames": ds.n_frames, "n_queries": n, "splits": splits(n),
        "reported_splits": list(REPORTED_SPLITS), "tolerance": dm.TOLERANCE,
        "l90_target": dm.TARGET, "recovery_hold": dm.HOLD, "settings": settings.model_dump(),
        "drives": {s: {p: {"drives": len(v), "frames": sum(len(d) for d in v)}
                       for p, v in d.items()} for s, d in drives.items()},
        "filter": config.model_dump(), "adaptation": adaptation,
        "odometry": {"available": odometry_supported(), "model": ODOMETRY_MODEL},
        "tuning": tuning, "methods": methods, "elapsed_seconds": time.perf_counter() - start,
    }  # fmt: skip

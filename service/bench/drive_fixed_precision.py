"""``gridplace bench drive-scaling --fixed-precision P``: the smallest code of a preset's family
that reaches a drive precision ``P``, per route length, and how those bytes grow.

For each route length N (SYNTHETIC routes, :func:`service.encoding.synthetic.write_route`) the
code's size is searched on **validation** routes and drives (``validation_seed``: another route
and other drives than the test's), then measured once on the **test** route and drives (the
bench's ``seed``, the routes and drives of :mod:`service.bench.drive_scaling`):

- the code's size is the fraction ``f = Στ / N`` (``code_ratio = f``, ``code_exponent = 1``
  over the preset): candidates lie on the grid ``f = 2^(-j/2)`` (steps of √2 in bytes);
- the search starts at a guess (``start_fraction``, else the preset's own ``Στ``, for the first
  length; the previous length's answer after it): it sets the search's cost, not its answer and steps down while the validation drives reach ``P``, up while
  they do not, so the answer is the smallest grid fraction that reaches it with the next one
  below failing (the precision is taken as non-decreasing in ``Στ``; drives are few, so a
  measured precision is noisy by a few points);
- with several ``emission_scales`` (the sequence filter's weight of one frame's evidence) the
  search runs for each, and the scale whose answer is smallest is kept (ties: the higher
  validation precision);
- the search stops at the code family's last code (:func:`floor_index`: two periods of
  ≈ √N for the ``drive`` preset), below which every grid point fits that same code;
- drive precision: the share of query frames of drives from an **unknown start**
  (:class:`~service.encoding.tracking.DriveTracker`, fresh) whose estimate lies within ±5
  frames of the truth; drives of ``drive_length`` frames, or with ``drive_share`` of that share
  of each route (:func:`drive_length_at`: drives that grow with the route, as a fleet's that
  covers it does); with ``odometry_noise``, drives carry SIMULATED odometry at that noise
  (:func:`~service.bench.drive_scaling.drive_odometry`).

Beside each answer stands what **any** map needs for the same drives
(:func:`information_bound_bytes`, Fano's inequality on places that look independent of one
another): the share of a drive's frames a filter can place within ±5 is bounded by how many
bits of the map the places seen so far can draw on, so a fixed precision at a fixed drive
length asks for bytes that grow as fast as ``N·log N``, whatever the code; with drives of a
fixed share of the route, as ``log N``.

The minimal code bytes are then fitted as ``c·N^a`` (``code_bytes_fit``), together with the test
precision at each; a length whose validation search does not reach ``P`` even at ``f = 1``
(``Στ = N``) is reported as not reached and left out of the fit.
"""

from __future__ import annotations

import math
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from service.bench.drive_protocols import MAX_SPEED
from service.bench.drive_scaling import (
    SIZES,
    _drive_rows,
    _fit_power,
    drive_odometry,
    filter_config,
)
from service.encoding.drive_scoring import drive_scorer
from service.encoding.factory import ModelParams, build_model
from service.encoding.presets import preset as preset_of
from service.encoding.residue import residue_periods
from service.encoding.synthetic import SYNTHETIC_LABEL, route_queries, write_route
from service.encoding.tracking import DriveTracker

MAX_STEPS = 12  # grid points one search may visit (a factor 2^6 in bytes either way)


@dataclass(frozen=True)
class FixedPrecisionOptions:
    target: float = 0.95
    sizes: tuple[int, ...] = SIZES
    n_features: int = 128
    query_noise: float = 0.4
    drives: int = 4
    drive_length: int = 300
    preset: str = "drive"
    seed: int = 0  # the test routes and drives
    validation_seed: int = 1
    emission_scales: tuple[float, ...] = (0.1,)
    start_fraction: float | None = None  # the first length's guess (default: the preset's Στ/N)
    overrides: dict[str, Any] = field(default_factory=dict)  # other fields of the code family
    odometry_noise: float | None = None  # SIMULATED odometry's level (None: drives without)
    drive_share: float | None = None  # drives of this share of each route (None: drive_length)


def drive_length_at(n_frames: int, opts: FixedPrecisionOptions) -> int:
    """Query frames per drive on a route of ``n_frames``: ``drive_share·N`` when the drives
    grow with the route, else the fixed ``drive_length``."""
    if opts.drive_share is None:
        return opts.drive_length
    return max(20, round(opts.drive_share * n_frames))


def floor_index(n_frames: int, opts: FixedPrecisionOptions) -> int:
    """The first grid point whose code is the family's last one at ``n_frames``: the periods
    :func:`~service.encoding.residue.residue_periods` falls back to when ``Στ`` is too small for
    any other (grown until their least common multiple covers the route, ``Στ ≈ k·N^(1/k)``).
    Every grid point past it fits that same code, so the search stops there."""
    k = int(opts.overrides.get("n_patterns", preset_of(opts.preset).n_patterns))
    last = residue_periods(n_frames, k, ratio=1e-12)
    j = max(0, math.ceil(-2 * math.log2(sum(last) / n_frames)))
    while residue_periods(n_frames, k, grid_fraction(j)) != last:
        j += 1  # a code smaller than the fallback may still exist just below it
    return j


def information_bound_bytes(n_frames: int, drive_length: int, precision: float,
                            radius: int = 5, max_speed: float = MAX_SPEED) -> float:  # fmt: skip
    """The fewest bytes with which any map and filter can place ``precision`` of the frames of
    drives of ``drive_length`` frames, from a uniformly unknown start, within ±``radius``, if the
    route's places look independent of one another (``inf``: no map can).

    After ``t`` frames the drive has seen at most ``w = max_speed·t + 1`` places; the map's
    ``S`` bits hold, averaged over starts, at most ``S·w/N`` bits about those (disjoint windows of
    independent places share the ``S`` bits), and the views do not depend on the start by
    themselves. Fano's inequality (list decoding into windows of ``2·radius + 1`` frames) then
    bounds the estimate at frame ``t`` to be right with probability at most
    ``min(1, (S·w/N + 1) / log2(N / (2·radius + 1)))``; the bound is the smallest ``S`` whose mean
    of that over the drive's frames reaches ``precision``. Odometry changes nothing here: it says
    how far the vehicle moved, not where it is."""
    cells = math.log2(n_frames / (2 * radius + 1))
    if cells <= 1:
        return 0.0
    seen = np.minimum(max_speed * np.arange(1, drive_length + 1) + 1.0, n_frames)

    def reach(bits: float) -> float:
        return float(np.mean(np.minimum(1.0, (bits * seen / n_frames + 1.0) / cells)))

    if reach(0.0) >= precision:
        return 0.0
    hi = n_frames * cells  # every frame right from the first
    if reach(hi) < precision:
        return math.inf
    lo = 0.0
    for _ in range(100):
        mid = 0.5 * (lo + hi)
        lo, hi = (lo, mid) if reach(mid) >= precision else (mid, hi)
    return hi / 8


def grid_fraction(j: int) -> float:
    """The ``j``-th code size of the search grid: ``Στ / N = 2^(-j/2)``."""
    return float(2.0 ** (-j / 2))


def grid_index(f: float) -> int:
    """The grid point nearest to fraction ``f`` (never above ``f = 1``)."""
    return max(0, round(-2 * math.log2(f)))


def drive_precision(
    ref: np.ndarray, model: Any, opts: FixedPrecisionOptions, seed: int, scale: float
) -> tuple[float, list[float]]:
    """Share of frames within ±5 over ``opts.drives`` drives from an unknown start, and each
    drive's share; drives and query noise drawn from ``seed``."""
    n = ref.shape[0]
    scorer = drive_scorer(model)
    config = filter_config(opts.odometry_noise, emission_scale=scale)
    rng = np.random.default_rng([seed, n])
    per_drive = []
    for d in range(opts.drives):
        rows = _drive_rows(n, drive_length_at(n, opts), rng)
        Q = route_queries(ref, rows, opts.query_noise, seed=seed * 1000 + d)
        odo = drive_odometry(rows, opts.odometry_noise, [seed, n, d])
        tracker = DriveTracker(scorer, config)
        est = np.array([tracker.update(p, u).index
                        for p, u in zip(scorer.prepare_many(Q), odo, strict=True)])
        per_drive.append(float(np.mean(np.abs(est - rows) <= 5)))
    return float(np.mean(per_drive)), per_drive


Evaluate = Callable[[int, float], dict[str, Any]]


def search(evaluate: Evaluate, start: int, target: float, scales: tuple[float, ...],
           smallest: int | None = None) -> dict[str, Any]:  # fmt: skip
    """The smallest grid code reaching ``target`` per emission scale (see the module doc);
    ``evaluate(j, scale)`` measures grid point ``j`` on validation and returns a record with
    ``precision``; ``smallest`` is the last grid point with a code of its own
    (:func:`floor_index`): an answer there is bounded by the code family, not by a failure.
    Returns the best scale's answer (``index`` ``None``: not reached at ``f = 1``) and every
    record measured."""
    trials: list[dict[str, Any]] = []
    answers = []
    for scale in scales:
        seen: dict[int, float] = {}

        def at(j: int, scale: float = scale, seen: dict[int, float] = seen) -> bool:
            if j not in seen:
                rec = evaluate(j, scale)
                trials.append(rec)
                seen[j] = float(rec["precision"])
            return seen[j] >= target

        j = max(0, start) if smallest is None else min(max(0, start), smallest)
        for _ in range(MAX_STEPS):
            if at(j):
                if j == smallest or (j + 1 in seen and not at(j + 1)):
                    break
                j += 1  # passes: try one step smaller
            else:
                if j == 0 or (j - 1 in seen and at(j - 1)):
                    break
                j -= 1  # fails: one step larger
        passing = [i for i, p in seen.items() if p >= target]
        best = max(passing) if passing else None
        # the answer is bounded when the next smaller code was measured and failed
        below = 0 if best is None else best + 1
        floor = best is not None and best == smallest
        bounded = floor or (below in seen and seen[below] < target)
        answers.append({"emission_scale": scale, "index": best, "bounded": bounded,
                        "family_floor": floor,
                        "precision": seen[best] if best is not None else max(seen.values())})  # fmt: skip
    found = [a for a in answers if a["index"] is not None]
    if found:
        chosen = max(found, key=lambda a: (a["index"], a["precision"]))
    else:
        chosen = max(answers, key=lambda a: a["precision"])
    return {"chosen": chosen, "answers": answers, "trials": trials}


def _fit(ref: np.ndarray, opts: FixedPrecisionOptions, f: float) -> tuple[Any, float]:
    t0 = time.perf_counter()
    params = ModelParams(encoder_preset=opts.preset, code_ratio=f, code_exponent=1.0,
                         **opts.overrides)  # fmt: skip
    return build_model(params).fit(ref), time.perf_counter() - t0


def _code_bytes(model: Any) -> int:
    return int(model.footprint().to_dict()["components"]["encoders"]["actual_bytes"])


def measure_size(n: int, opts: FixedPrecisionOptions, start: int, workdir: Path,
                 log: Callable[[str], None]) -> dict[str, Any]:  # fmt: skip
    """One route length: the validation search, then the test measurement at its answer."""
    val = write_route(workdir / f"val-{n}.npy", n, opts.n_features, seed=opts.validation_seed)
    models: dict[int, tuple[Any, float]] = {}

    def evaluate(j: int, scale: float) -> dict[str, Any]:
        if j not in models:
            models.clear()  # one fitted model at a time (a 1M model is large)
            models[j] = _fit(val, opts, grid_fraction(j))
        model, fit_s = models[j]
        t0 = time.perf_counter()
        prec, per = drive_precision(val, model, opts, opts.validation_seed, scale)
        rec = {"index": j, "fraction": grid_fraction(j), "emission_scale": scale,
               "periods": [int(p) for p in model.periods_], "code_bytes": _code_bytes(model),
               "precision": prec, "per_drive": per, "fit_s": fit_s,
               "drives_s": time.perf_counter() - t0}  # fmt: skip
        log(f"N = {n:,} validation: Στ/N = {rec['fraction']:.4f} (Στ = {sum(rec['periods']):,}, "
            f"{rec['code_bytes']:,} B), emission scale {scale:g}: {100 * prec:.1f} %")
        return rec

    found = search(evaluate, start, opts.target, opts.emission_scales, floor_index(n, opts))
    models.clear()
    del val
    (workdir / f"val-{n}.npy").unlink(missing_ok=True)
    chosen = found["chosen"]
    length = drive_length_at(n, opts)
    bound = information_bound_bytes(n, length, opts.target)
    out: dict[str, Any] = {"n_frames": n, "drive_length": length, "validation": found,
                           "reached": chosen["index"] is not None, "bound_bytes": bound}  # fmt: skip
    if chosen["index"] is None:
        return out
    ref = write_route(workdir / f"test-{n}.npy", n, opts.n_features, seed=opts.seed)
    model, fit_s = _fit(ref, opts, grid_fraction(chosen["index"]))
    prec, per = drive_precision(ref, model, opts, opts.seed, chosen["emission_scale"])
    out |= {"fraction": sum(model.periods_) / n, "grid_fraction": grid_fraction(chosen["index"]),
            "index": chosen["index"], "family_floor": chosen["family_floor"],
            "emission_scale": chosen["emission_scale"],
            "periods": [int(p) for p in model.periods_], "code_bytes": _code_bytes(model),
            "map_bytes": int(model.footprint().to_dict()["actual_bytes"]),
            "test_precision": prec, "test_per_drive": per, "fit_s": fit_s}  # fmt: skip
    log(f"N = {n:,} test: Στ = {sum(out['periods']):,}, {out['code_bytes']:,} B, "
        f"{100 * prec:.1f} % (target {100 * opts.target:.0f} %)")
    return out


def preset_start(n: int, opts: FixedPrecisionOptions) -> int:
    """The grid point of the preset's own code at ``n`` frames (the first search's guess)."""
    p = preset_of(opts.preset)
    periods = residue_periods(n, p.n_patterns, p.code_ratio, p.code_exponent)
    return grid_index(sum(periods) / n)


def run_fixed_precision(opts: FixedPrecisionOptions, workdir: Path | None = None,
                        log: Callable[[str], None] = print) -> dict[str, Any]:  # fmt: skip
    """Every size of ``opts`` (see the module doc), in ascending order."""
    results: list[dict[str, Any]] = []
    with tempfile.TemporaryDirectory(dir=workdir) as tmp:
        start = None if opts.start_fraction is None else grid_index(opts.start_fraction)
        for n in sorted(opts.sizes):
            guess = preset_start(n, opts) if start is None else start
            r = measure_size(n, opts, guess, Path(tmp), log)
            results.append(r)
            if r["reached"]:
                start = r["index"]
    out: dict[str, Any] = {
        "data": SYNTHETIC_LABEL,
        "mode": "fixed-precision",
        "options": opts.__dict__ | {"sizes": list(opts.sizes),
                                    "emission_scales": list(opts.emission_scales)},
        "filter": filter_config(opts.odometry_noise).model_dump(),
        "sizes": results,
    }  # fmt: skip
    reached = [r for r in results if r["reached"]]
    if len(reached) >= 2:
        out["code_bytes_fit"] = _fit_power([r["n_frames"] for r in reached],
                                           [r["code_bytes"] for r in reached])  # fmt: skip
        out["map_bytes_fit"] = _fit_power([r["n_frames"] for r in reached],
                                          [r["map_bytes"] for r in reached])  # fmt: skip
    if len(results) >= 2 and all(0 < r["bound_bytes"] < math.inf for r in results):
        out["bound_bytes_fit"] = _fit_power([r["n_frames"] for r in results],
                                            [r["bound_bytes"] for r in results])  # fmt: skip
    return out

"""``gridplace bench drive-scaling``: the ``drive`` preset on SYNTHETIC routes of growing length.

For each route length N (default 10k, 100k, 1M frames of a SYNTHETIC smooth random-process
route, :func:`service.encoding.synthetic.write_route`, labelled so in every output): fit the
``drive`` preset, then drive it — several drives from random starts at variable speed (0.5–2
reference frames per query frame, changing smoothly) whose query frames are the reference plus
fresh noise — through the windowed tracker (:class:`~service.encoding.tracking.DriveTracker`)
and the whole-route filter (``tracking=False``, today's cost). It reports per N: the code's
bytes (class templates) and the whole map's, the drive precision within ±5 frames, the single
frames' precision, and the per-frame cost of each filter (CPU time per update; the tracker's
over frames it spent in windows mode; and on drives started at their known first place,
:meth:`~service.encoding.tracking.DriveTracker.start_at`, so that the tracker's cost is
measured on every length even where the evidence does not concentrate the belief), and fits
``bytes ≈ c·N^a`` over the lengths. With ``odometry_noise`` every drive frame also carries
SIMULATED odometry (the true displacement with that noise,
:func:`~service.bench.drive_protocols.noisy_odometry`), and the filter is told that noise. CPU
times are measured with one BLAS thread, as the server runs.
"""

from __future__ import annotations

import math
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from service.bench.drive_bench import stated
from service.bench.drive_protocols import MAX_SPEED, MIN_SPEED, noisy_odometry, true_motion
from service.encoding.drive_scoring import drive_scorer
from service.encoding.factory import ModelParams, build_model
from service.encoding.sequence import SequenceConfig, SequenceFilter
from service.encoding.synthetic import SYNTHETIC_LABEL, route_queries, write_route
from service.encoding.tracking import DriveTracker

SIZES = (10_000, 100_000, 1_000_000)
BLAS_THREADS = 1  # the serving default (``Settings.serve_blas_threads``)


@dataclass(frozen=True)
class ScalingOptions:
    sizes: tuple[int, ...] = SIZES
    n_features: int = 128
    query_noise: float = 0.6
    drives: int = 8
    drive_length: int = 300
    whole_frames: int = 30  # frames timed through the whole-route filter (O(S·N) each)
    preset: str = "drive"
    seed: int = 0
    odometry_noise: float | None = None  # SIMULATED odometry's level (None: drives without)


def speed_profile(n: int, rng: np.random.Generator) -> np.ndarray:
    """A smoothly varying speed in [MIN_SPEED, MAX_SPEED] = [0.5, 2] reference frames per query
    frame."""
    phase, period = rng.uniform(0, 2 * np.pi), rng.uniform(40, 160)
    mid, half = 0.5 * (MIN_SPEED + MAX_SPEED), 0.5 * (MAX_SPEED - MIN_SPEED)
    return mid + half * np.sin(phase + 2 * np.pi * np.arange(n) / period)


def _drive_rows(n_frames: int, length: int, rng: np.random.Generator) -> np.ndarray:
    speed = speed_profile(length, rng)
    span = float(speed.sum()) + 2
    start = rng.uniform(0, max(1.0, n_frames - span))
    return np.minimum(np.rint(start + np.cumsum(speed) - speed[0]).astype(np.int64), n_frames - 1)


def drive_odometry(rows: np.ndarray, level: float | None, seed: list[int]) -> list[float | None]:
    """Each frame's SIMULATED odometry (:func:`~service.bench.drive_protocols.noisy_odometry`
    of the true displacement at ``level``), or ``None`` per frame for drives without."""
    if level is None:
        return [None] * int(rows.size)
    return [float(u) for u in noisy_odometry(true_motion(rows), level, seed)]


def filter_config(level: float | None, **fields: Any) -> SequenceConfig:
    """The filter's defaults (with ``fields``), stating the odometry noise ``level`` when the
    drives have odometry."""
    config = SequenceConfig.parse(**fields)
    return config if level is None else stated(config, level)


def _fit_power(x: list[float], y: list[float]) -> dict[str, float]:
    lx, ly = np.log(np.asarray(x, float)), np.log(np.asarray(y, float))
    a, logc = np.polyfit(lx, ly, 1)
    return {"exponent": float(a), "prefactor": float(math.exp(logc))}


def measure_size(n: int, opts: ScalingOptions, workdir: Path) -> dict[str, Any]:
    """One route length: fit, bytes, drives through both filters."""
    ref = write_route(workdir / f"route-{n}.npy", n, opts.n_features, seed=opts.seed)
    t0 = time.process_time()
    wall0 = time.perf_counter()
    model = build_model(ModelParams(encoder_preset=opts.preset)).fit(ref)
    fit_cpu, fit_wall = time.process_time() - t0, time.perf_counter() - wall0
    fp = model.footprint().to_dict()
    code_bytes = int(fp["components"]["encoders"]["actual_bytes"])
    scorer = drive_scorer(model)
    config = filter_config(opts.odometry_noise)
    rng = np.random.default_rng([opts.seed, n])
    hits, singles, track_us, frames_windowed, frames_total = [], [], [], 0, 0
    cold_us, cold_whole = [], []
    for d in range(opts.drives):
        rows = _drive_rows(n, opts.drive_length, rng)
        Q = route_queries(ref, rows, opts.query_noise, seed=opts.seed * 1000 + d)
        preps = scorer.prepare_many(Q)
        singles.append(np.abs(model.localize(Q).index - rows) <= 5)
        odo = drive_odometry(rows, opts.odometry_noise, [opts.seed, n, d])
        tracker = DriveTracker(scorer, config)
        est = np.empty(rows.size, dtype=np.int64)
        for t, prep in enumerate(preps):
            windowed = tracker.mode == "windows"
            c0 = time.process_time_ns()
            est[t] = tracker.update(prep, odo[t]).index
            dt = time.process_time_ns() - c0
            cold_us.append(dt / 1e3)
            cold_whole.append(not windowed or tracker.mode == "whole")
            if windowed:
                track_us.append(dt / 1e3)
                frames_windowed += 1
            frames_total += 1
        hits.append(np.abs(est - rows) <= 5)
    # the tracker's cost once it tracks, whatever the evidence: drives that start at a known
    # place (start_at), every frame in windows mode
    seeded_us, seeded_hits, seeded_all_us, seeded_whole = [], [], [], []
    for d in range(max(1, opts.drives // 2)):
        rows = _drive_rows(n, opts.drive_length, rng)
        Q = route_queries(ref, rows, opts.query_noise, seed=opts.seed * 1000 + 500 + d)
        odo = drive_odometry(rows, opts.odometry_noise, [opts.seed, n, 500 + d])
        tracker = DriveTracker(scorer, config)
        tracker.start_at(int(rows[0]))
        for t, prep in enumerate(scorer.prepare_many(Q)):
            windowed = tracker.mode == "windows"
            c0 = time.process_time_ns()
            index = tracker.update(prep, odo[t]).index
            dt_us = (time.process_time_ns() - c0) / 1e3
            seeded_all_us.append(dt_us)
            seeded_whole.append(not windowed or tracker.mode == "whole")
            if windowed:
                seeded_us.append(dt_us)
            seeded_hits.append(abs(index - int(rows[t])) <= 5)
    # the whole-route filter's cost per frame (a few frames of the first drive's scores)
    rows = _drive_rows(n, opts.whole_frames, rng)
    Q = route_queries(ref, rows, opts.query_noise, seed=opts.seed * 1000 + 999)
    preps = scorer.prepare_many(Q)
    odo = drive_odometry(rows, opts.odometry_noise, [opts.seed, n, 999])
    whole = SequenceFilter(n, config)
    whole_us = []
    for prep, u in zip(preps, odo, strict=True):
        c0 = time.process_time_ns()
        whole.update(scorer.full(prep), u)
        whole_us.append((time.process_time_ns() - c0) / 1e3)
    return {
        "n_frames": n,
        "periods": [int(p) for p in getattr(model, "periods_", ())],
        "code_bytes": code_bytes,
        "map_bytes": int(fp["actual_bytes"]),
        "fit_cpu_s": fit_cpu,
        "fit_wall_s": fit_wall,
        "drive_precision": float(np.concatenate(hits).mean()),
        "single_frame_precision": float(np.concatenate(singles).mean()),
        "tracking_us_per_frame": float(np.median(track_us)) if track_us else None,
        "tracking_us_mean": float(np.mean(track_us)) if track_us else None,
        "windowed_share": frames_windowed / max(1, frames_total),
        "seeded_tracking_us_per_frame": float(np.median(seeded_us)) if seeded_us else None,
        "seeded_drive_precision": float(np.mean(seeded_hits)) if seeded_hits else None,
        # every frame, windows mode or not ("whole": the frame ran on, or went to, the route)
        "seeded_us_mean": float(np.mean(seeded_all_us)),
        "seeded_us_p99": float(np.percentile(seeded_all_us, 99)),
        "seeded_whole_share": float(np.mean(seeded_whole)),
        "unknown_start_us_mean": float(np.mean(cold_us)),
        "unknown_start_us_p99": float(np.percentile(cold_us, 99)),
        "unknown_start_whole_share": float(np.mean(cold_whole)),
        "whole_filter_us_per_frame": float(np.median(whole_us)),
        "states": int(whole.speeds.size),
    }


def run_drive_scaling(opts: ScalingOptions, workdir: Path | None = None) -> dict[str, Any]:
    """Every size of ``opts`` (see the module doc); SYNTHETIC routes, written under
    ``workdir`` (a temporary folder by default) and removed afterwards."""
    from threadpoolctl import threadpool_limits

    results = []
    # one BLAS thread, as the server runs (GRIDPLACE_SERVE_BLAS_THREADS=1): a library's idle
    # threads spinning after each small product would count as the filter's CPU time
    with tempfile.TemporaryDirectory(dir=workdir) as tmp, threadpool_limits(BLAS_THREADS):
        for n in opts.sizes:
            results.append(measure_size(n, opts, Path(tmp)))
            (Path(tmp) / f"route-{n}.npy").unlink(missing_ok=True)
    sizes = [r["n_frames"] for r in results]
    out: dict[str, Any] = {
        "data": SYNTHETIC_LABEL,
        "options": opts.__dict__ | {"sizes": list(opts.sizes)},
        "filter": filter_config(opts.odometry_noise).model_dump(),
        "blas_threads": BLAS_THREADS,
        "sizes": results,
    }
    if len(sizes) >= 2:
        out["code_bytes_fit"] = _fit_power(sizes, [r["code_bytes"] for r in results])
        out["map_bytes_fit"] = _fit_power(sizes, [r["map_bytes"] for r in results])
        first, last = results[0], results[-1]
        if first["tracking_us_per_frame"] and last["tracking_us_per_frame"]:
            out["tracking_cost_ratio"] = last["tracking_us_per_frame"] / first["tracking_us_per_frame"]
        if first["seeded_tracking_us_per_frame"] and last["seeded_tracking_us_per_frame"]:
            out["seeded_tracking_cost_ratio"] = (last["seeded_tracking_us_per_frame"]
                                                 / first["seeded_tracking_us_per_frame"])  # fmt: skip
        out["seeded_mean_cost_ratio"] = last["seeded_us_mean"] / first["seeded_us_mean"]
        out["whole_cost_ratio"] = last["whole_filter_us_per_frame"] / first["whole_filter_us_per_frame"]
    return out

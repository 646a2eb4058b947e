"""``gridplace bench drive --tune``: the filter's parameters chosen on half A's drives.

Every configuration of the grid (the base configuration with ``emission_scale``,
``stop_probability``, ``relocalization`` and ``speed_change`` replaced, and ``speed_jump`` or
``start_probability`` where ``--grid`` names them) drives every A drive
of every method without odometry. The objective is the mean, over the protocols, of their
precision within ±5 frames (a short drive counts every one of its frames; a kidnap counts its
frames before and after the jump). ``per-method`` picks each method's best; ``shared`` the
best mean over the methods. Half B and the whole route are then reported with the choice.
"""

from __future__ import annotations

import itertools
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from service.bench import drive_protocols as dp
from service.bench.drive_bench import evaluate
from service.encoding.sequence import SequenceConfig
from service.errors import InvalidParameterError

TUNE_MODES: tuple[str, ...] = ("off", "shared", "per-method")
TUNED: tuple[str, ...] = (
    "emission_scale", "stop_probability", "relocalization", "speed_change", "speed_jump",
    "start_probability",
)  # fmt: skip
DEFAULT_GRID: dict[str, tuple[float, ...]] = {
    "emission_scale": (0.05, 0.1, 0.2, 0.4),
    "stop_probability": (0.0, 0.02),
    "relocalization": (1e-4, 1e-3),
    "speed_change": (0.01, 0.05),
}


def parse_grid(items: list[str] | None) -> dict[str, tuple[float, ...]]:
    """``--grid KEY=V1,V2,…`` options over :data:`DEFAULT_GRID` (the keys of :data:`TUNED`; a
    key outside the default grid adds a dimension)."""
    grid = dict(DEFAULT_GRID)
    for item in items or []:
        key, sep, values = item.partition("=")
        key = key.strip()
        if not sep or key not in TUNED:
            raise InvalidParameterError(
                f"--grid must be KEY=V1,V2 with KEY one of {', '.join(TUNED)}; got {item!r}"
            )
        try:
            grid[key] = tuple(float(v) for v in values.split(",") if v.strip())
        except ValueError as exc:
            raise InvalidParameterError(f"--grid {key}: not numbers: {values!r}") from exc
        if not grid[key]:
            raise InvalidParameterError(f"--grid {key} has no values")
    return grid


def candidates(base: SequenceConfig, grid: dict[str, tuple[float, ...]]) -> list[SequenceConfig]:
    keys = list(grid)
    return [SequenceConfig.parse(**{**base.model_dump(), **dict(zip(keys, values, strict=True))})
            for values in itertools.product(*(grid[k] for k in keys))]  # fmt: skip


def objective(figures: dict[str, Any]) -> float:
    return float(np.mean([f["precision"] for f in figures.values()]))


def tune_configs(scores: dict[str, np.ndarray], drives: dict[str, list[dp.Drive]],
                 base: SequenceConfig, mode: str, grid: dict[str, tuple[float, ...]] | None,
                 seed: int, progress: Callable[[str], None]) -> dict[str, Any]:  # fmt: skip
    """Every candidate on every method's A drives; the chosen configuration per method."""
    if mode not in TUNE_MODES[1:]:
        raise InvalidParameterError(f"tune mode must be one of {', '.join(TUNE_MODES[1:])}")
    if not drives:
        raise InvalidParameterError("half A is too short for any drive: nothing to tune on")
    cands = candidates(base, grid or DEFAULT_GRID)
    rows: list[dict[str, Any]] = []
    start = time.perf_counter()
    for k, cfg in enumerate(cands):
        progress(f"tuning on A: candidate {k + 1}/{len(cands)}")
        per = {m: objective(evaluate(S, drives, cfg, None, seed)) for m, S in scores.items()}
        rows.append({"config": {t: getattr(cfg, t) for t in TUNED}, "objective": per,
                     "mean": float(np.mean(list(per.values())))})  # fmt: skip
    if mode == "shared":
        best = max(rows, key=lambda r: r["mean"])["config"]
        chosen = {m: {**base.model_dump(), **best} for m in scores}
    else:
        chosen = {m: {**base.model_dump(), **max(rows, key=lambda r: r["objective"][m])["config"]}
                  for m in scores}  # fmt: skip
    return {
        "split": "A", "mode": mode, "grid": {k: list(v) for k, v in (grid or DEFAULT_GRID).items()},
        "objective": "mean over protocols of precision within ±5 frames, no odometry",
        "candidates": rows, "chosen": chosen, "seconds": time.perf_counter() - start,
    }  # fmt: skip

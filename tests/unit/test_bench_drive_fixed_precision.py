"""``gridplace bench drive-scaling --fixed-precision``: the search for the smallest code that
reaches a drive precision, and the mode end to end on small SYNTHETIC routes."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

from hypothesis import given, settings
from hypothesis import strategies as st
from typer.testing import CliRunner, Result

from service.bench.drive_fixed_precision import (
    Evaluate,
    FixedPrecisionOptions,
    drive_length_at,
    floor_index,
    grid_fraction,
    grid_index,
    information_bound_bytes,
    search,
)
from service.bench.drive_scaling import _fit_power
from service.cli import app
from service.encoding.residue import residue_periods


def _threshold(last: int, calls: list[tuple[int, float]],
               scale_shift: dict[float, int] | None = None) -> Evaluate:
    """A precision curve that reaches the target for grid points ``j <= last`` (larger codes)."""

    def evaluate(j: int, scale: float) -> dict[str, Any]:
        calls.append((j, scale))
        edge = last + (scale_shift or {}).get(scale, 0)
        return {"precision": 0.99 if j <= edge else 0.5 + 0.01 * (20 - j)}

    return evaluate


@settings(max_examples=200, deadline=None)
@given(last=st.integers(-1, 9), start=st.integers(0, 10))
def test_the_search_finds_the_smallest_passing_code_from_any_start(last: int, start: int) -> None:
    calls: list[tuple[int, float]] = []
    out = search(_threshold(last, calls), start, 0.95, (0.1,))
    chosen = out["chosen"]
    assert chosen["index"] == (last if last >= 0 else None)
    assert chosen["bounded"]  # the next smaller code (or f = 1 when none passes) was measured
    assert len(calls) == len(set(calls)) <= abs(start - last) + 2  # each point measured once
    assert len(out["trials"]) == len(calls)


@settings(max_examples=100, deadline=None)
@given(smallest=st.integers(0, 9), start=st.integers(0, 12))
def test_the_search_stops_at_the_code_familys_smallest_code(smallest: int, start: int) -> None:
    calls: list[tuple[int, float]] = []
    out = search(_threshold(30, calls), start, 0.95, (0.1,), smallest=smallest)
    chosen = out["chosen"]
    assert chosen["index"] == smallest and chosen["family_floor"] and chosen["bounded"]
    assert max(j for j, _ in calls) == smallest  # never past the floor


@settings(max_examples=20, deadline=None)
@given(case=st.one_of(st.tuples(st.integers(1_000, 2_000_000), st.just(2)),
                     # three periods of ≈ N^(1/3): scoring their aliases costs (N/τ)² each
                     st.tuples(st.integers(1_000, 20_000), st.just(3))))
def test_the_floor_index_is_the_first_grid_point_at_the_familys_last_code(
    case: tuple[int, int],
) -> None:
    n, k = case
    opts = FixedPrecisionOptions(overrides={"n_patterns": k})
    j = floor_index(n, opts)
    last = residue_periods(n, k, ratio=1e-12)
    assert all(residue_periods(n, k, grid_fraction(i)) == last for i in (j, j + 1, j + 4))
    assert j == 0 or residue_periods(n, k, grid_fraction(j - 1)) != last
    if k == 2:  # the drive preset's family: its last code is its smallest
        assert math.prod(last) >= n and sum(last) <= 2 * math.isqrt(n) + 4


def test_the_scale_with_the_smallest_code_is_kept() -> None:
    calls: list[tuple[int, float]] = []
    out = search(_threshold(3, calls, {0.3: 2}), 4, 0.95, (0.1, 0.3))
    assert out["chosen"]["emission_scale"] == 0.3 and out["chosen"]["index"] == 5
    assert [a["index"] for a in out["answers"]] == [3, 5]


def test_the_grid_steps_by_root_two() -> None:
    assert grid_fraction(0) == 1.0 and abs(grid_fraction(2) - 0.5) < 1e-12
    assert all(grid_index(grid_fraction(j)) == j for j in range(20))
    assert grid_index(1.0) == 0 and grid_index(0.3) == 3  # 0.3 is nearest to 2^-1.5 = 0.354


def _fixed_precision(tmp_path: Path, *drives: str) -> tuple[Result, dict[str, Any]]:
    """The mode at 90 % on SYNTHETIC routes of 2,000 and 4,000 frames, one drive each."""
    out = tmp_path / "fixed.json"
    result = CliRunner().invoke(app, ["bench", "drive-scaling", "--fixed-precision", "0.9",
                                      "--sizes", "2000,4000", "--drives", "1", *drives,
                                      "--query-noise", "0.2",
                                      "--work-dir", str(tmp_path), "--out", str(out)])  # fmt: skip
    assert result.exit_code == 0, result.output
    return result, json.loads(out.read_text())


def test_the_fixed_precision_mode_writes_its_figures(tmp_path: Path) -> None:
    result, data = _fixed_precision(tmp_path, "--drive-length", "100")
    assert data["data"].startswith("SYNTHETIC") and data["mode"] == "fixed-precision"
    assert [r["n_frames"] for r in data["sizes"]] == [2000, 4000]
    for r in data["sizes"]:
        trials = r["validation"]["trials"]
        assert trials and all(0 <= t["precision"] <= 1 for t in trials)
        assert r["reached"]
        chosen = r["validation"]["chosen"]
        assert chosen["precision"] >= 0.9 and r["index"] == chosen["index"]
        # the answer's code on the test route is the size searched on validation
        assert r["fraction"] == sum(r["periods"]) / r["n_frames"]
        assert r["family_floor"] or abs(r["fraction"] - r["grid_fraction"]) < 0.01
        assert 0 <= r["test_precision"] <= 1 and r["code_bytes"] < r["map_bytes"]
        smaller = [t for t in trials if t["index"] == r["index"] + 1
                   and t["emission_scale"] == r["emission_scale"]]
        assert all(t["precision"] < 0.9 for t in smaller)
    assert "exponent" in data["code_bytes_fit"] and "minimal code bytes" in result.output
    assert all(0 < r["bound_bytes"] < r["code_bytes"] for r in data["sizes"])
    assert data["bound_bytes_fit"]["exponent"] > 1.0 and "any map needs" in result.output
    bad = CliRunner().invoke(app, ["bench", "drive-scaling", "--fixed-precision", "0.9",
                                   "--emission-scales", "0.1,-1"])  # fmt: skip
    assert bad.exit_code == 2


def test_drives_may_grow_with_the_route(tmp_path: Path) -> None:
    _, data = _fixed_precision(tmp_path, "--drive-share", "0.05")
    assert [r["drive_length"] for r in data["sizes"]] == [100, 200]
    for r in data["sizes"]:
        assert r["reached"] and r["test_precision"] >= 0.5
        assert r["bound_bytes"] == information_bound_bytes(r["n_frames"], r["drive_length"], 0.9)
        trials = r["validation"]["trials"]
        last = floor_index(r["n_frames"], FixedPrecisionOptions())
        assert max(t["index"] for t in trials) <= last
    for share in ("0", "0.9"):
        bad = CliRunner().invoke(app, ["bench", "drive-scaling", "--fixed-precision", "0.9",
                                       "--drive-share", share])  # fmt: skip
        assert bad.exit_code == 2


def test_a_drive_share_sets_each_routes_drive_length() -> None:
    opts = FixedPrecisionOptions(drive_share=0.1)
    assert [drive_length_at(n, opts) for n in (1_000, 10_000)] == [100, 1_000]
    assert drive_length_at(10_000, FixedPrecisionOptions(drive_length=300)) == 300


def test_the_information_bound_of_one_frame_is_fanos() -> None:
    # one frame that sees one place: right with probability (S/N + 1)/log2(N/11) at most
    n, p = 11 * 2**10, 0.6
    bound = information_bound_bytes(n, 1, p, max_speed=0.0)
    assert abs(8 * bound - n * (p * 10 - 1)) < 1e-6 * n


@settings(max_examples=100, deadline=None)
@given(n=st.integers(1_000, 10**7), length=st.integers(1, 2_000), p=st.floats(0.2, 0.999))
def test_the_information_bound_is_the_least_map_that_reaches_the_precision(
    n: int, length: int, p: float
) -> None:
    bound = information_bound_bytes(n, length, p)
    assert 0 <= bound < math.inf
    # more frames per drive never need more bytes, a longer route or a higher share never fewer
    assert information_bound_bytes(n, 2 * length, p) <= bound + 1e-6
    assert information_bound_bytes(2 * n, length, p) >= bound - 1e-6
    assert information_bound_bytes(n, length, min(1.0, p + 0.001)) >= bound - 1e-6


def test_the_information_bound_grows_faster_than_the_route_at_a_fixed_drive() -> None:
    sizes = [10_000, 100_000, 1_000_000]
    fit = _fit_power(sizes, [information_bound_bytes(n, 300, 0.95) for n in sizes])
    assert fit["exponent"] > 1.0  # N·log N: no code keeps a < 1 at a fixed drive length


def test_the_information_bound_grows_as_log_n_when_drives_grow_with_the_route() -> None:
    sizes = [10_000, 100_000, 1_000_000]
    bounds = [information_bound_bytes(n, n // 10, 0.95) for n in sizes]
    fit = _fit_power(sizes, bounds)
    assert 0 < fit["exponent"] < 0.2  # about log N: a drive sees a fixed share of the route

"""``gridplace bench drive-scaling`` end to end on small SYNTHETIC routes."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from typer.testing import CliRunner

from service.bench.drive_scaling import (
    _drive_rows,
    _fit_power,
    drive_odometry,
    filter_config,
    speed_profile,
)
from service.cli import app


def test_the_power_fit_recovers_exponent_and_prefactor() -> None:
    x = [1e4, 1e5, 1e6]
    fit = _fit_power(x, [3.0 * v**0.5 for v in x])
    assert abs(fit["exponent"] - 0.5) < 1e-9 and abs(fit["prefactor"] - 3.0) < 1e-6


def test_drives_stay_on_the_route_at_speeds_between_half_and_two() -> None:
    rng = np.random.default_rng(0)
    assert 0.5 - 1e-9 <= speed_profile(500, rng).min() and speed_profile(500, rng).max() <= 2.0 + 1e-9
    rows = _drive_rows(5_000, 400, rng)
    assert rows.min() >= 0 and rows.max() < 5_000 and np.all(np.diff(rows) >= 0)


def test_the_bench_writes_its_figures(tmp_path: Path) -> None:
    out = tmp_path / "scaling.json"
    result = CliRunner().invoke(app, ["bench", "drive-scaling", "--sizes", "2000,4000", "--drives", "1",
                                      "--drive-length", "120", "--work-dir", str(tmp_path),
                                      "--out", str(out)])  # fmt: skip
    assert result.exit_code == 0, result.output
    data = json.loads(out.read_text())
    assert data["data"].startswith("SYNTHETIC") and [r["n_frames"] for r in data["sizes"]] == [2000, 4000]
    for r in data["sizes"]:
        assert r["code_bytes"] < r["map_bytes"] and 0 <= r["drive_precision"] <= 1
        assert r["whole_filter_us_per_frame"] > 0
    assert 0.3 < data["code_bytes_fit"]["exponent"] < 0.7  # Στ ∝ √N
    assert "code bytes fit" in result.output
    bad = CliRunner().invoke(app, ["bench", "drive-scaling", "--sizes", "10,x"])
    assert bad.exit_code == 2


def test_drive_odometry_is_the_true_displacement_at_zero_noise() -> None:
    rows = np.array([4, 5, 7, 7, 10])
    assert drive_odometry(rows, None, [0]) == [None] * 5
    assert drive_odometry(rows, 0.0, [0]) == [0.0, 1.0, 2.0, 0.0, 3.0]
    noisy = drive_odometry(rows, 0.1, [0])
    assert noisy != drive_odometry(rows, 0.0, [0]) and noisy == drive_odometry(rows, 0.1, [0])
    assert filter_config(0.2).odometry_noise == 0.2 and filter_config(None).odometry_noise == 0.1


def test_drives_with_odometry_are_tracked_and_say_so(tmp_path: Path) -> None:
    out = tmp_path / "scaling.json"
    result = CliRunner().invoke(app, ["bench", "drive-scaling", "--sizes", "2000", "--drives", "1",
                                      "--drive-length", "120", "--odometry-noise", "0.05",
                                      "--query-noise", "0.2", "--work-dir", str(tmp_path),
                                      "--out", str(out)])  # fmt: skip
    assert result.exit_code == 0, result.output
    data = json.loads(out.read_text())
    assert data["options"]["odometry_noise"] == 0.05 and data["filter"]["odometry_noise"] == 0.05
    assert data["sizes"][0]["seeded_drive_precision"] > 0.9
    bad = CliRunner().invoke(app, ["bench", "drive-scaling", "--odometry-noise", "-1"])
    assert bad.exit_code == 2

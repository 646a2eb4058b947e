"""``gridplace bench drive-scaling``: the drive preset's bytes, precision and per-frame cost
on SYNTHETIC routes of growing length (see :mod:`service.bench.drive_scaling`)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer
from rich.console import Console
from rich.table import Table

from service.cli.errors import cli_errors
from service.cli.paths import output_file, writable_dir

if TYPE_CHECKING:
    from service.bench.drive_fixed_precision import FixedPrecisionOptions

console = Console()


def _sizes(text: str) -> tuple[int, ...]:
    try:
        sizes = tuple(int(float(s)) for s in text.split(",") if s.strip())
    except ValueError:
        raise typer.BadParameter(f"sizes are comma-separated frame counts, got {text!r}") from None
    if not sizes or min(sizes) < 1_000:
        raise typer.BadParameter("every size must be at least 1,000 frames")
    return sizes


def _scales(text: str) -> tuple[float, ...]:
    try:
        scales = tuple(float(s) for s in text.split(",") if s.strip())
    except ValueError:
        raise typer.BadParameter(f"emission scales are comma-separated numbers, got {text!r}") from None
    if not scales or min(scales) <= 0:
        raise typer.BadParameter("every emission scale must be positive")
    return scales


def _fixed(opts: FixedPrecisionOptions, work_dir: Path | None, out: Path) -> None:
    from service.bench.drive_fixed_precision import run_fixed_precision

    result = run_fixed_precision(opts, work_dir, log=console.print)
    table = Table(title=f"{opts.preset} preset on {result['data']}: smallest code reaching "
                  f"{100 * opts.target:.0f} % within ±5 (chosen on validation seed "
                  f"{opts.validation_seed}, measured on test seed {opts.seed})")  # fmt: skip
    for col in ("N", "drive frames", "Στ/N", "periods", "emission scale", "code B",
                "any map needs, B", "validation", "test drive ±5"):  # fmt: skip
        table.add_column(col, justify="right")
    for r in result["sizes"]:
        chosen = r["validation"]["chosen"]
        bound = f"{r['bound_bytes']:,.0f}"
        if not r["reached"]:
            table.add_row(f"{r['n_frames']:,}", f"{r['drive_length']:,}", "not reached", "", "",
                          "", bound, f"{100 * chosen['precision']:.1f} %", "")  # fmt: skip
            continue
        fraction = f"{r['fraction']:.4f}" + (" (floor)" if r["family_floor"] else "")
        table.add_row(f"{r['n_frames']:,}", f"{r['drive_length']:,}", fraction,
                      "+".join(map(str, r["periods"])), f"{r['emission_scale']:g}",
                      f"{r['code_bytes']:,}", bound, f"{100 * chosen['precision']:.1f} %",
                      f"{100 * r['test_precision']:.1f} %")  # fmt: skip
    console.print(table)
    for key, what in (("code_bytes_fit", "minimal code bytes"),
                      ("bound_bytes_fit", "bytes any map needs (independent places)")):  # fmt: skip
        if key in result:
            fit = result[key]
            console.print(f"{what}: {fit['prefactor']:.3g}·N^{fit['exponent']:.3f}")
    out.write_text(json.dumps(result, indent=2))
    console.print(f"wrote {out}")


@cli_errors
def bench_drive_scaling(
    sizes: Annotated[str, typer.Option(help="route lengths N, comma-separated")] = "10000,100000,1000000",
    n_features: Annotated[int, typer.Option(help="descriptor size d of the SYNTHETIC route", min=8)] = 128,
    query_noise: Annotated[float, typer.Option(help="query noise (unit-variance columns)", min=0.0)] = 0.6,
    drives: Annotated[int, typer.Option(help="drives per route length", min=1)] = 8,
    drive_length: Annotated[int, typer.Option(help="query frames per drive", min=20)] = 300,
    preset: Annotated[str, typer.Option(help="encoder preset")] = "drive",
    work_dir: Annotated[Path | None, typer.Option(help="where the SYNTHETIC routes are written")] = None,
    out: Annotated[Path, typer.Option(help="JSON output")] = Path("bench-drive-scaling.json"),
    fixed_precision: Annotated[float | None, typer.Option(
        help="instead: per N, the smallest code (Στ/N on a grid of steps of √2, searched on "
        "validation drives) whose drives from an unknown start reach this share of frames "
        "within ±5, measured on the test drives, and the fit c·N^a of those bytes",
        min=0.01, max=1.0)] = None,
    validation_seed: Annotated[int, typer.Option(
        help="--fixed-precision: seed of the validation routes and drives", min=1)] = 1,
    emission_scales: Annotated[str, typer.Option(
        help="--fixed-precision: the filter's emission scales searched (comma-separated); the "
        "one with the smallest code on validation is kept")] = "0.1",
    start_fraction: Annotated[float | None, typer.Option(
        help="--fixed-precision: the first length's guess of Στ/N (the search's cost, not its "
        "answer; default: the preset's own code)", min=1e-6, max=1.0)] = None,
    odometry_noise: Annotated[float | None, typer.Option(
        help="drives carry SIMULATED odometry: the true displacement with this noise (a "
        "fraction of it, and in frames), stated to the filter; default: no odometry",
        min=0.0, max=10.0)] = None,
    drive_share: Annotated[float | None, typer.Option(
        help="--fixed-precision: drives of this share of each route instead of --drive-length "
        "frames (drives that grow with the route; at most 0.75, so that a drive's span at "
        "up to 2 frames per frame fits the route)", min=0.001, max=0.75)] = None,
) -> None:
    """Bytes (fitted as c·N^a), drive precision and per-frame filter cost (windowed tracker
    beside the whole-route filter) of a preset on SYNTHETIC routes of each length; with
    --fixed-precision, the smallest code reaching a drive precision per length instead."""
    from service.bench.drive_fixed_precision import FixedPrecisionOptions
    from service.bench.drive_scaling import ScalingOptions, run_drive_scaling

    work_dir = writable_dir(work_dir, "--work-dir")
    out = output_file(out, "--out")
    if fixed_precision is not None:
        fixed = FixedPrecisionOptions(fixed_precision, _sizes(sizes), n_features, query_noise,
                                      drives, drive_length, preset, seed=0,
                                      validation_seed=validation_seed,
                                      emission_scales=_scales(emission_scales),
                                      start_fraction=start_fraction,
                                      odometry_noise=odometry_noise,
                                      drive_share=drive_share)  # fmt: skip
        _fixed(fixed, work_dir, out)
        return

    opts = ScalingOptions(_sizes(sizes), n_features, query_noise, drives, drive_length,
                          preset=preset, odometry_noise=odometry_noise)  # fmt: skip
    result = run_drive_scaling(opts, work_dir)
    table = Table(title=f"{preset} preset on {result['data']}")
    for col in ("N", "code B", "map B", "fit s", "drive ±5", "single ±5", "tracking µs/frame",
                "windowed", "whole filter µs/frame"):  # fmt: skip
        table.add_column(col, justify="right")
    for r in result["sizes"]:
        track = r["tracking_us_per_frame"]
        table.add_row(f"{r['n_frames']:,}", f"{r['code_bytes']:,}", f"{r['map_bytes']:,}",
                      f"{r['fit_wall_s']:.1f}", f"{100 * r['drive_precision']:.1f} %",
                      f"{100 * r['single_frame_precision']:.1f} %",
                      "—" if track is None else f"{track:.0f}", f"{100 * r['windowed_share']:.0f} %",
                      f"{r['whole_filter_us_per_frame']:.0f}")  # fmt: skip
    console.print(table)
    for key in ("code_bytes_fit", "map_bytes_fit"):
        if key in result:
            fit = result[key]
            console.print(f"{key.replace('_', ' ')}: {fit['prefactor']:.3g}·N^{fit['exponent']:.3f}")
    for r in result["sizes"]:
        if r["seeded_tracking_us_per_frame"] is not None:
            console.print(f"N = {r['n_frames']:,}: tracking from a known start "
                          f"{r['seeded_tracking_us_per_frame']:.0f} µs/frame, "
                          f"{100 * r['seeded_drive_precision']:.1f} % within ±5; every frame "
                          f"mean {r['seeded_us_mean']:.0f}, p99 {r['seeded_us_p99']:.0f} µs, "
                          f"{100 * r['seeded_whole_share']:.1f} % on the whole route")  # fmt: skip
    if "seeded_tracking_cost_ratio" in result:
        console.print(f"tracking from a known start, largest N / smallest: "
                      f"{result['seeded_tracking_cost_ratio']:.2f}×")
    if "tracking_cost_ratio" in result:
        console.print(f"tracking cost, largest N / smallest: {result['tracking_cost_ratio']:.2f}×; "
                      f"whole filter: {result['whole_cost_ratio']:.1f}×")  # fmt: skip
    out.write_text(json.dumps(result, indent=2))
    console.print(f"wrote {out}")

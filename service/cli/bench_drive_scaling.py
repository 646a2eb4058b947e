"""``gridplace bench drive-scaling``: the drive preset's bytes, precision and per-frame cost
on SYNTHETIC routes of growing length (see :mod:`service.bench.drive_scaling`)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console
from rich.table import Table

console = Console()


def _sizes(text: str) -> tuple[int, ...]:
    try:
        sizes = tuple(int(float(s)) for s in text.split(",") if s.strip())
    except ValueError:
        raise typer.BadParameter(f"sizes are comma-separated frame counts, got {text!r}") from None
    if not sizes or min(sizes) < 1_000:
        raise typer.BadParameter("every size must be at least 1,000 frames")
    return sizes


def bench_drive_scaling(
    sizes: Annotated[str, typer.Option(help="route lengths N, comma-separated")] = "10000,100000,1000000",
    n_features: Annotated[int, typer.Option(help="descriptor size d of the SYNTHETIC route", min=8)] = 128,
    query_noise: Annotated[float, typer.Option(help="query noise (unit-variance columns)", min=0.0)] = 0.6,
    drives: Annotated[int, typer.Option(help="drives per route length", min=1)] = 8,
    drive_length: Annotated[int, typer.Option(help="query frames per drive", min=20)] = 300,
    preset: Annotated[str, typer.Option(help="encoder preset")] = "drive",
    work_dir: Annotated[Path | None, typer.Option(help="where the SYNTHETIC routes are written")] = None,
    out: Annotated[Path, typer.Option(help="JSON output")] = Path("bench-drive-scaling.json"),
) -> None:
    """Bytes (fitted as c·N^a), drive precision and per-frame filter cost (windowed tracker
    beside the whole-route filter) of a preset on SYNTHETIC routes of each length."""
    from service.bench.drive_scaling import ScalingOptions, run_drive_scaling

    opts = ScalingOptions(_sizes(sizes), n_features, query_noise, drives, drive_length,
                          preset=preset)  # fmt: skip
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

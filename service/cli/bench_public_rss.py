"""``gridplace bench public-rss``: what unauthenticated callers can make a server hold."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated

import typer

from service.cli.errors import cli_errors
from service.cli.paths import output_file


@cli_errors
def bench_public_rss(
    n_frames: Annotated[int, typer.Option(help="route length N of the SYNTHETIC map served")] = 20_000,
    vehicle_d: Annotated[int, typer.Option(
        help="descriptor size of the map REST vehicles and JSON batches use (2,048 lets the "
             "vehicles fill their byte budget)")] = 2048,
    seconds: Annotated[float, typer.Option(help="how long drives, batches and slow bodies run")] = 60.0,
    rest_vehicles: Annotated[int | None, typer.Option(
        help="REST vehicles created (default GRIDPLACE_MAX_REST_VEHICLES)")] = None,
    setting: Annotated[list[str] | None, typer.Option(
        "--set", help="a server setting, GRIDPLACE_NAME=VALUE (repeatable; default: the defaults)")] = None,
    out: Annotated[Path | None, typer.Option(help="JSON (default docs/benchmarks/public-rss-DATE.json)")] = None,
) -> None:
    """The worst unauthenticated load at once against a real server (REST vehicles, every gRPC
    stream with its vehicles, worst drives, batches at the body limit, bodies that never end):
    peak RSS above the baseline beside the bound docs/RELIABILITY.md states."""
    from datetime import UTC, datetime

    from service.bench.public_rss import run_public_rss_bench
    from service.errors import InvalidParameterError

    env = {}
    for item in setting or ():
        key, sep, value = item.partition("=")
        if not sep or not key.startswith("GRIDPLACE_"):
            raise InvalidParameterError(f"--set takes GRIDPLACE_NAME=VALUE, not {item!r}")
        env[key] = value
    path = output_file(out or Path("docs/benchmarks") / f"public-rss-{datetime.now(UTC):%Y-%m-%d}.json",
                       "--out")  # fmt: skip
    report = run_public_rss_bench(n_frames, vehicle_d, seconds, env, path, rest_vehicles)
    bound = report["bound_mib"]
    typer.echo(f"baseline {report['baseline_mib']:.0f} MiB; peak above it "
               f"{report['peak_above_baseline_mib']:.0f} MiB; bound {bound['total']:.0f} MiB "
               f"({report['peak_over_bound']:.2f} of it)")  # fmt: skip
    for term, mib in bound.items():
        typer.echo(f"  {term:22s} {mib:9.1f} MiB")
    typer.echo(json.dumps(report["load"]))
    typer.echo(f"written to {path}")

"""``gridplace bench drive``: drive protocols, every method through the same sequence filter."""

from __future__ import annotations

import json
import sys
from datetime import UTC, datetime
from pathlib import Path
from typing import Annotated, Any

import numpy as np
import typer
from rich.console import Console

from service.cli.errors import cli_errors
from service.cli.paths import output_file

console = Console() if sys.stdout.isatty() else Console(width=180)  # logs keep whole rows


def _default_out() -> Path:
    return Path("docs/benchmarks") / f"drive-{datetime.now(UTC):%Y-%m-%d}.json"


def _floats(text: str, option: str) -> tuple[float, ...]:
    from service.errors import InvalidParameterError

    try:
        values = tuple(float(v) for v in text.split(",") if v.strip())
    except ValueError as exc:
        raise InvalidParameterError(f"{option}: not numbers: {text!r}") from exc
    if any(not np.isfinite(v) or v < 0 for v in values):
        raise InvalidParameterError(f"{option}: noise levels must be finite and >= 0")
    return values


@cli_errors
def bench_drive(
    dataset: Annotated[Path | None, typer.Argument(
        help="dataset folder: reference/ + query/ image folders and/or reference.npy + "
             "query.npy (pixels patch-normalised); default: Nordland in the shared data")] = None,
    reference: Annotated[Path | None, typer.Option(help="reference descriptors .npy")] = None,
    query: Annotated[Path | None, typer.Option(help="query descriptors .npy (with --reference)")] = None,
    ground_truth: Annotated[Path | None, typer.Option(
        help="int .npy: query i -> reference frame (default: frame-aligned)")] = None,
    name: Annotated[str | None, typer.Option(
        help="name of a --reference/--query pair in the output (default: its folder's)")] = None,
    synthetic: Annotated[int | None, typer.Option(help="a SYNTHETIC route of N frames instead")] = None,
    extractor: Annotated[str | None, typer.Option(
        help="run the folder's reference/ and query/ images through this image extractor "
             "(patchnorm | hog | cnn, as `gridplace extract`; written beside --out)")] = None,
    methods: Annotated[str | None, typer.Option(
        help="comma-separated: exact-nn, pq-mM, residue-rR, residue-kK-rR, or any preset "
             "(default: exact-nn, pq-m64, robust, residue r=0.1/0.034, k=3 r=0.013, ridge, "
             "drive)")] = None,
    protocols: Annotated[str, typer.Option(help="comma-separated")] = "whole,short,speed,traffic,kidnap,reverse",
    drives: Annotated[int, typer.Option("--drives", help="short drives from random starts")] = 100,
    short_length: Annotated[int, typer.Option(
        "--short-length", "--short-lengths", help="frames of each short drive (L = 1 … this)")] = 200,
    speed_drives: Annotated[int, typer.Option(help="variable-speed drives per speed profile")] = 3,
    speed_frames: Annotated[int, typer.Option(help="query frames of a variable-speed drive, at most")] = 600,
    traffic_drives: Annotated[int, typer.Option(help="drives of the second variable-speed generator (traffic)")] = 9,
    stop_noise: Annotated[float, typer.Option(help="traffic: a stopped vehicle's near-identical frames, descriptor noise relative to the frame's norm")] = 0.03,
    kidnap_drives: Annotated[int, typer.Option(help="kidnapped drives")] = 20,
    kidnap_before: Annotated[int, typer.Option(help="frames before the jump")] = 150,
    kidnap_after: Annotated[int, typer.Option(help="frames after the jump")] = 250,
    min_jump: Annotated[int, typer.Option(help="the jump is at least this many frames")] = 200,
    odometry_noise: Annotated[str, typer.Option(
        help="SIMULATED odometry noise levels, comma-separated ('' for none)")] = "0.05,0.1,0.2",
    adapt: Annotated[bool, typer.Option(help="appearance adaptation of the queries")] = True,
    filter_params: Annotated[list[str] | None, typer.Option(
        "--filter", metavar="KEY=VALUE", help="sequence filter parameter (default: its defaults)")] = None,
    tune: Annotated[str, typer.Option(help="off | shared | per-method: grid search on half A")] = "off",
    grid: Annotated[list[str] | None, typer.Option(
        "--grid", metavar="KEY=V1,V2", help="tuning grid values (emission_scale, "
        "stop_probability, relocalization, speed_change; speed_jump, start_probability add a "
        "dimension)")] = None,
    seed: Annotated[int, typer.Option(help="seed of every drive generator")] = 0,
    patch: Annotated[int, typer.Option(help="patchnorm patch side for pixel datasets")] = 16,
    out: Annotated[Path | None, typer.Option(help="JSON (default docs/benchmarks/drive-DATE.json)")] = None,
    markdown: Annotated[Path | None, typer.Option(help="also write the tables as Markdown")] = None,
    figure: Annotated[Path | None, typer.Option(
        help="PNG of drive precision and L90 against map bytes (default: beside the JSON)")] = None,
    report_from: Annotated[Path | None, typer.Option(
        "--report", help="run nothing: print this JSON report's tables (and --markdown, "
                         "--figure)")] = None,
) -> None:
    """Localise moving vehicles: the whole drive, short drives from random starts (L90),
    variable speed with stops, traffic (cruising, braking, long stops), a kidnapped vehicle and
    a backwards drive, with and without
    SIMULATED odometry; every method through the same filter; half A tunes, B reports."""
    from service.bench.drive_bench import DriveSettings, run_drive_bench
    from service.bench.drive_data import load_route
    from service.bench.drive_methods import methods as pick_methods
    from service.bench.drive_tuning import parse_grid
    from service.cli.model_commands import sequence_config
    from service.errors import InvalidParameterError

    if markdown is not None:
        markdown = output_file(markdown, "--markdown")
    if report_from is not None:
        from service.errors import InvalidInputError

        try:
            report = json.loads(report_from.read_text())
        except (OSError, ValueError) as exc:
            raise InvalidInputError(f"cannot read the report {report_from}: {exc}") from exc
        if report.get("benchmark") != "drive":
            raise InvalidInputError(f"{report_from} is not a `gridplace bench drive` report")
        _outputs(report, markdown, figure or report_from.with_suffix(".png"))
        return
    chosen_protocols = tuple(p.strip() for p in protocols.split(",") if p.strip())
    try:
        settings = DriveSettings(
            protocols=chosen_protocols, short_drives=drives, short_length=short_length,
            speed_drives=speed_drives, speed_frames=speed_frames, traffic_drives=traffic_drives,
            stop_noise=stop_noise, kidnap_drives=kidnap_drives,
            kidnap_before=kidnap_before, kidnap_after=kidnap_after, min_jump=min_jump,
            odometry_noise=_floats(odometry_noise, "--odometry-noise"), adapt=adapt, seed=seed)
    except ValueError as exc:  # pydantic's ValidationError is a ValueError
        raise InvalidParameterError(f"invalid drive settings: {exc}") from exc
    from service.bench.drive_bench import PROTOCOLS

    unknown = [p for p in chosen_protocols if p not in PROTOCOLS]
    if unknown or not chosen_protocols:
        raise InvalidParameterError(f"unknown protocol(s) {unknown}; choose from {PROTOCOLS}")
    chosen = pick_methods(methods)
    config = sequence_config(filter_params)
    tuning_grid = parse_grid(grid)
    out = output_file(out or _default_out(), "--out")
    ds = load_route(dataset, reference, query, ground_truth, synthetic, patch, name, extractor,
                    out.parent / "extracted")  # fmt: skip
    with console.status("starting") as status:
        report = run_drive_bench(ds, chosen, settings, config, tune, tuning_grid,
                                 progress=lambda m: status.update(m),
                                 argv=["gridplace", *sys.argv[1:]])  # fmt: skip
    tmp = out.with_name(out.name + ".tmp")
    tmp.write_text(json.dumps(report, indent=2))
    tmp.replace(out)
    _outputs(report, markdown, figure or out.with_suffix(".png"))
    console.print(f"wrote {out} ({report['elapsed_seconds'] / 60:.1f} min)")


def _outputs(report: dict[str, Any], markdown: Path | None, figure: Path) -> None:
    """The tables on the console, the Markdown file and the figure of one report."""
    from service.bench.drive_report import markdown as to_markdown
    from service.bench.drive_report import plot, print_report

    print_report(report, console)
    if markdown is not None:
        markdown.write_text(to_markdown(report))
        console.print(f"wrote {markdown}")
    png = plot(report, figure)
    console.print(f"wrote {png}" if png else "matplotlib is not installed: no figure")

"""``gridplace client …``: talk to a running gridplace server through :mod:`service.client`.

The server is ``--url`` or ``GRIDPLACE_URL`` (default http://127.0.0.1:8080); admin calls send
``GRIDPLACE_ADMIN_TOKEN`` (or ``--token``, which other users can see in ``ps``).
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import numpy as np
import typer
from rich.table import Table

from service.cli.append_command import append
from service.cli.client_job_follow import follow_job, report_job
from service.cli.client_options import (
    AsJson,
    ConditionOption,
    MapName,
    Timeout,
    Token,
    Url,
    WaitTimeout,
    console,
    open_client,
    print_json,
    when,
)
from service.cli.console import plural, print_table
from service.cli.errors import cli_errors
from service.client import JobFailedError
from service.client.calls import options_of
from service.encoding.phases import parse_periods
from service.encoding.presets import DEFAULT_PRESET, PRESETS
from service.errors import InvalidInputError
from service.npyfile import load_npy

app = typer.Typer(help="Talk to a running gridplace server (REST).", no_args_is_help=True)


def _rows(spec: str | None, n: int) -> slice:
    if not spec:
        return slice(0, n)
    try:
        if ":" in spec:
            a, _, b = spec.partition(":")
            return slice(int(a) if a else 0, int(b) if b else n)
        i = int(spec)
        return slice(i, i + 1)
    except ValueError as exc:
        raise InvalidInputError(f"--rows must be START:STOP or an index, got {spec!r}") from exc


def _load_queries(path: Path, rows: str | None) -> tuple[np.ndarray, int]:
    X = np.asarray(load_npy(path))
    X = X[None, :] if X.ndim == 1 else X
    sl = _rows(rows, X.shape[0])
    Q = X[sl]
    if Q.shape[0] == 0:
        raise InvalidInputError(f"--rows {rows!r} selects no row of {path} ({X.shape[0]} rows)")
    return Q, sl.start or 0


@app.command()
@cli_errors
def localize(
    map_name: MapName,
    npy: Annotated[
        Path | None, typer.Option("--npy", help=".npy query descriptors (one per row)")
    ] = None,
    rows: Annotated[str | None, typer.Option(help="rows of --npy: START:STOP or one index")] = None,
    image: Annotated[
        list[Path] | None, typer.Option("--image", "-i", help="image file (repeatable)")
    ] = None,
    condition: ConditionOption = None,
    url: Url = None,
    timeout: Timeout = 30.0,
    as_json: AsJson = False,
) -> None:
    """Localize descriptors (--npy, sent as binary float32) or images (--image) on MAP."""
    if (npy is None) == (not image):
        raise InvalidInputError("give exactly one of --npy or --image")
    with open_client(url, None, timeout) as gp:
        if npy is not None:
            Q, first = _load_queries(npy, rows)
            batch = gp.localize_batch(map_name, Q, condition)
            labels = [str(first + i) for i in range(batch.n)]
        else:
            assert image is not None
            batch = gp.localize_images(map_name, image, condition)
            labels = [p.name for p in image]
    if as_json:
        print_json(batch)
        return
    cond = f", condition {batch.condition}" if batch.condition else ""
    table = Table(
        title=f"{batch.map} v{batch.version}: {plural(batch.n, 'query', 'queries')} in "
        f"{batch.latency_ms:.1f} ms{cond}"
    )
    for col in ("query", "frame index", "chunk", "confidence"):
        table.add_column(col, justify="right")
    for label, idx, chunk, conf in zip(
        labels, batch.index, batch.chunk, batch.confidence, strict=True
    ):
        table.add_row(label, str(idx), str(chunk), f"{conf:.3f}")
    print_table(console, table)


@app.command()
@cli_errors
def upload(
    map_name: MapName,
    routes: Annotated[list[Path], typer.Argument(
        metavar="ROUTE", help=".npy/.npz descriptors or .zip/.tar of images; several files are traversals of "
        "the same places (frame-aligned, or with --places)", show_default=False)],
    places: Annotated[list[Path] | None, typer.Option(
        "--places", help="int .npy: the place (0..N-1) of every row of one route file; give "
        "it once per file, in the files' order", show_default=False)] = None,
    preset: Annotated[str | None, typer.Option(help=f"encoder preset: {' | '.join(PRESETS)} "
        f"(default: the server's, {DEFAULT_PRESET}; see gridplace train --help)")] = None,
    trainer: Annotated[str | None, typer.Option(
        help="logreg (the paper's) | svm | ridge | torch | prototype (the default preset's)")] = None,
    patterns: Annotated[
        int | None, typer.Option("--patterns", "-k", help="number of encoders k")
    ] = None,
    periods: Annotated[str | None, typer.Option(help="explicit periods, e.g. 60,60")] = None,
    rho: Annotated[float | None, typer.Option(help="fraction of columns per encoder")] = None,
    c: Annotated[float | None, typer.Option("--C", help="inverse regularisation")] = None,
    dtype: Annotated[str | None, typer.Option(help="float64 | float32 | float16 | int8 | binary (sign bits: class templates)")] = None,
    chunks: Annotated[int | None, typer.Option(help="number of chunks")] = None,
    extractor: Annotated[
        str | None, typer.Option(help="patchnorm | hog | cnn (image archives)")
    ] = None,
    param: Annotated[
        list[str] | None,
        typer.Option(
            "--param",
            "-p",
            help="any other training/extractor option as KEY=VALUE "
            "(e.g. -p width=64 -p height=32 -p top_chunks=3), repeatable",
        ),
    ] = None,
    idempotency_key: Annotated[
        str | None, typer.Option(help="same key → same job on a retry")
    ] = None,
    wait: Annotated[
        bool, typer.Option("--wait/--no-wait", help="follow the job until it ends")
    ] = False,
    wait_timeout: WaitTimeout = 3600.0,
    url: Url = None,
    token: Token = None,
    timeout: Timeout = 30.0,
    as_json: AsJson = False,
) -> None:
    """Upload ROUTE (one file per traversal) and train a new version of MAP (exit 2 if the
    job fails with --wait)."""
    parsed = parse_periods(periods, "--periods")
    period_list = list(parsed) if parsed is not None else None
    given = {"encoder_preset": preset, "trainer": trainer, "n_patterns": patterns, "periods": period_list, "rho": rho,
             "C": c, "dtype": dtype, "n_chunks": chunks, "extractor": extractor}  # fmt: skip
    extra: dict[str, object] = {}
    for item in param or []:
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            raise InvalidInputError(f"--param must be KEY=VALUE, got {item!r}")
        extra[key.strip()] = value.split(",") if key.strip() == "periods" else value.strip()
    options = options_of(None, {**extra, **{k: v for k, v in given.items() if v is not None}})
    with open_client(url, token, timeout) as gp:
        size = sum(r.stat().st_size for r in routes if r.is_file())
        with console.status(f"uploading {', '.join(r.name for r in routes)} ({size:,} B)"):
            job = gp.upload_route(map_name, routes[0] if len(routes) == 1 else routes, options,
                                  idempotency_key=idempotency_key, places=places)  # fmt: skip
        if not wait:
            if as_json:
                print_json(job)
            else:
                console.print(f"job {job.id} {job.state}; follow it with: gridplace client jobs {job.id} --wait",
                              highlight=False)  # fmt: skip
            return
        job = follow_job(gp, job, wait_timeout)
        report_job(gp, job, as_json)


@app.command()
@cli_errors
def jobs(
    job_ids: Annotated[list[str] | None, typer.Argument(
        metavar="[JOB_ID...]", help="job ids; none: list the newest jobs")] = None,
    map_name: Annotated[str | None, typer.Option("--map", help="list only this map's")] = None,
    state: Annotated[list[str] | None, typer.Option(help="list only these states")] = None,
    limit: Annotated[int, typer.Option(min=1, max=500, help="jobs to list")] = 20,
    wait: Annotated[
        bool, typer.Option("--wait/--no-wait", help="wait until each job ends")
    ] = False,
    wait_timeout: WaitTimeout = 3600.0,
    url: Url = None,
    token: Token = None,
    timeout: Timeout = 30.0,
    as_json: AsJson = False,
) -> None:
    """Show training jobs (state, stage, fit progress, retries, version); exit 2 if one of
    the given jobs failed. Without ids: the newest jobs (--map, --state, --limit)."""
    with open_client(url, token, timeout) as gp:
        if not job_ids:
            found = gp.list_jobs(map_name, state, limit).jobs
        else:
            found = [(follow_job(gp, gp.get_job(j), wait_timeout) if wait else gp.get_job(j))
                     for j in job_ids]  # fmt: skip
    if as_json:
        print_json(found)
    else:
        table = Table()
        for col in ("job", "map", "state", "stage", "progress", "retries", "version", "created",
                    "finished", "error"):  # fmt: skip
            table.add_column(col)
        for j in found:
            done = f"{j.progress.fraction:.0%}" + (f" {j.progress.detail}" if not j.done else "")
            table.add_row(j.id, j.map, j.state, j.stage, done, str(len(j.retries)),
                          str(j.version) if j.version is not None else "-", when(j.created_at),
                          when(j.finished_at), j.error or "")  # fmt: skip
        print_table(console, table)
    failed = [j.id for j in found if j.state == "failed"]
    if failed and job_ids:
        raise JobFailedError(f"failed: {', '.join(failed)}")


@app.command()
@cli_errors
def status(url: Url = None, timeout: Timeout = 10.0, as_json: AsJson = False) -> None:
    """Liveness and readiness of the server (exit 2 if it cannot be reached)."""
    with open_client(url, None, timeout) as gp:
        gp.health()
        ready = gp.ready()
    if as_json:
        print_json(ready)
        return
    loaded = ", ".join(f"{m} v{v}" for m, v in ready.loaded.items()) or "no map"
    console.print(f"{gp.base_url}: alive, {'ready' if ready.ready else 'NOT ready'}; serving {loaded}"
                  + (f"; pending {', '.join(ready.pending)}" if ready.pending else "")
                  + (f"; errors {ready.errors}" if ready.errors else ""), highlight=False)  # fmt: skip


@app.command()
@cli_errors
def maps(
    url: Url = None, token: Token = None, timeout: Timeout = 30.0, as_json: AsJson = False
) -> None:
    """List every map with its active version."""
    with open_client(url, token, timeout) as gp:
        found = gp.list_maps()
    if as_json:
        print_json(found)
        return
    table = Table()
    for col in ("map", "active", "versions", "created"):
        table.add_column(col)
    for m in found:
        active = str(m.active_version) if m.active_version is not None else "-"
        table.add_row(m.name, active, ",".join(map(str, m.versions)), when(m.created_at))
    if found:
        print_table(console, table)
    else:
        console.print("no maps yet")


@app.command()
@cli_errors
def versions(
    map_name: MapName,
    url: Url = None,
    token: Token = None,
    timeout: Timeout = 30.0,
    as_json: AsJson = False,
) -> None:
    """List the versions of MAP: size, footprint, training metrics."""
    with open_client(url, token, timeout) as gp:
        found = gp.list_versions(map_name)
    if as_json:
        print_json(found)
        return
    table = Table(title=f"map {map_name}")
    for col in ("version", "active", "kind", "preset", "frames", "traversals", "d",
                "stored bytes", "P@0 (train)", "created"):  # fmt: skip
        table.add_column(col, no_wrap=col in ("kind", "created"))
    for v in found:
        p0 = v.metrics.get("train_precision_at_0")
        table.add_row(str(v.version), "*" if v.active else "", v.kind,
                      str(v.params.get("encoder_preset") or "-"), str(v.n_frames),
                      str(v.n_traversals), str(v.n_features),
                      f"{v.footprint.get('actual_bytes', v.artifact_bytes):,}",
                      f"{p0:.3f}" if isinstance(p0, (int, float)) else "-", when(v.created_at))  # fmt: skip
    print_table(console, table)


@app.command()
@cli_errors
def activate(
    map_name: MapName,
    version: Annotated[int, typer.Argument(help="version to serve")],
    url: Url = None,
    token: Token = None,
    timeout: Timeout = 30.0,
    as_json: AsJson = False,
) -> None:
    """Serve VERSION of MAP (promote or roll back; the server hot-swaps)."""
    with open_client(url, token, timeout) as gp:
        v = gp.activate(map_name, version)
    if as_json:
        print_json(v)
    else:
        console.print(f"map {v.map}: version {v.version} is active", highlight=False)


@app.command()
@cli_errors
def deactivate(
    map_name: MapName,
    url: Url = None,
    token: Token = None,
    timeout: Timeout = 30.0,
) -> None:
    """Take MAP out of service (localize answers 409 until a version is activated)."""
    with open_client(url, token, timeout) as gp:
        gp.deactivate(map_name)
    console.print(f"map {map_name}: out of service", highlight=False)


@app.command()
@cli_errors
def delete(
    map_name: MapName,
    version: Annotated[int, typer.Argument(help="an inactive version")],
    url: Url = None,
    token: Token = None,
    timeout: Timeout = 30.0,
) -> None:
    """Delete an inactive VERSION of MAP."""
    with open_client(url, token, timeout) as gp:
        gp.delete_version(map_name, version)
    console.print(f"map {map_name}: version {version} deleted", highlight=False)


app.command()(append)


def register(root: typer.Typer) -> None:
    root.add_typer(app, name="client")

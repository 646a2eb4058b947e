"""``gridplace bench …``: benchmarks that print figures and write JSON."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from service.cli.errors import cli_errors
from service.cli.paths import output_file, writable_dir

app = typer.Typer(help="Benchmarks (figures printed and written as JSON).", no_args_is_help=True)


@app.command("train")
@cli_errors
def bench_train(
    n_frames: Annotated[int, typer.Option(help="route length N")] = 10_000,
    n_features: Annotated[int, typer.Option(help="descriptor size d")] = 4096,
    patterns: Annotated[int, typer.Option(help="k")] = 2,
    rho: Annotated[float, typer.Option()] = 0.5,
    trainers: Annotated[str, typer.Option(help="comma-separated")] = "logreg,svm,ridge,torch",
    out: Annotated[Path, typer.Option(help="JSON output")] = Path("bench-train.json"),
) -> None:
    """Training time, precision@5, query time and footprint per trainer, in one run."""
    out = output_file(out, "--out")
    from service.bench.train_bench import run_train_bench

    run_train_bench(n_frames, n_features, patterns, rho, trainers.split(","), out)


@app.command("workers")
@cli_errors
def bench_workers(
    n_frames: Annotated[int, typer.Option(help="route length N (Nordland when present)")] = 3576,
    n_features: Annotated[int, typer.Option(help="d of the SYNTHETIC route without Nordland")] = 2048,
    chunks: Annotated[int, typer.Option(help="n_chunks")] = 8,
    workers: Annotated[int, typer.Option(help="workers of the scaled run")] = 2,
    trainer: Annotated[str, typer.Option()] = "ridge",
    registry_url: Annotated[str | None, typer.Option(
        help="PostgreSQL registry (default: a scratch database on GRIDPLACE_TEST_POSTGRES_URL)")] = None,
    out: Annotated[Path, typer.Option(help="JSON output")] = Path("bench-workers.json"),
) -> None:
    """A chunked route trained by 1 and by N RQ workers on a PostgreSQL registry (one run)."""
    out = output_file(out, "--out")
    from service.bench.workers_bench import run_workers_bench

    run_workers_bench(n_frames, n_features, chunks, workers, trainer, registry_url, out)


def _overrides(trainer: str | None, patterns: int | None) -> dict[str, str]:
    """Fields given on the command line over the preset's (``--preset robust`` alone is the
    default as it ships, not its front-end under another trainer)."""
    out = {} if trainer is None else {"trainer": trainer}
    return out if patterns is None else {**out, "n_patterns": str(patterns)}


@app.command("serve")
@cli_errors
def bench_serve(
    n_frames: Annotated[int, typer.Option(help="route length N of the served map")] = 10_000,
    single: Annotated[int, typer.Option(help="single-descriptor requests per form")] = 500,
    batch_queries: Annotated[int, typer.Option(help="queries sent in batches")] = 4096,
    batch_size: Annotated[int, typer.Option(help="queries per batch request")] = 256,
    trainer: Annotated[str | None, typer.Option(help="the preset's own unless given")] = None,
    patterns: Annotated[int | None, typer.Option(help="k (the preset's own unless given)")] = None,
    chunks: Annotated[int, typer.Option(help="n_chunks")] = 1,
    preset: Annotated[str, typer.Option(
        help="encoder preset; the docs/RESULTS Serving tables use ridge (the paper's mixed-radix "
             "code with the ridge trainer)")] = "ridge",
    compare: Annotated[bool, typer.Option(help="also measure a server without micro-batching")] = True,
    out: Annotated[Path, typer.Option(help="JSON output")] = Path("bench-serve.json"),
) -> None:
    """/localize p50/p99 latency and batch throughput of a real server on loopback (10k map),
    micro-batched and not, beside the in-process fast path and reference decoder."""
    out = output_file(out, "--out")
    from service.bench.serve_bench import run_serve_bench

    params = {"encoder_preset": preset, "n_chunks": str(chunks), **_overrides(trainer, patterns)}
    run_serve_bench(n_frames, single, batch_queries, batch_size, params, out, compare)


@app.command("grpc")
@cli_errors
def bench_grpc(
    n_frames: Annotated[int, typer.Option(help="route length N of the served maps")] = 10_000,
    frames: Annotated[int, typer.Option(help="frames sent, on 1 stream and split over --streams")] = 4000,
    streams: Annotated[int, typer.Option(help="concurrent streams")] = 8,
    rest_batch: Annotated[int, typer.Option(help="queries per REST batch request")] = 256,
    query_noise: Annotated[float, typer.Option(help="noise of the SYNTHETIC filter route")] = 1.0,
    noisy_d: Annotated[int, typer.Option(help="descriptor size of the SYNTHETIC filter route")] = 256,
    trainer: Annotated[str | None, typer.Option(help="the preset's own unless given")] = None,
    patterns: Annotated[int | None, typer.Option(help="k (the preset's own unless given)")] = None,
    window: Annotated[int, typer.Option(help="frames in flight per stream")] = 16,
    preset: Annotated[str, typer.Option(
        help="encoder preset; the docs/RESULTS Serving tables use ridge (the paper's mixed-radix "
             "code with the ridge trainer)")] = "ridge",
    compare: Annotated[bool, typer.Option(help="also measure a server without micro-batching")] = True,
    floor: Annotated[bool, typer.Option(
        help="also measure the streams against a server that does no work (the gRPC floor), in "
             "the same rounds, and give gridplace's server CPU per frame against it")] = True,
    wait_grid: Annotated[str, typer.Option(
        help="micro-batch waits to compare, ms, comma-separated (e.g. 0,0.5,2; empty: none)")] = "",
    grid_frames: Annotated[int, typer.Option(help="frames per wait of the grid (5 rounds)")] = 15_000,
    out: Annotated[Path, typer.Option(help="JSON output")] = Path("bench-grpc.json"),
) -> None:
    """gRPC frames/s on 1 and N streams beside REST, micro-batched and not, and what sequence
    filtering does to precision."""
    out = output_file(out, "--out")
    from service.bench.grpc_bench import run_grpc_bench

    params = {"encoder_preset": preset, **_overrides(trainer, patterns)}
    waits = [float(w) for w in wait_grid.split(",") if w.strip()]
    run_grpc_bench(n_frames, frames, streams, rest_batch, query_noise, noisy_d, params, out,
                   window, compare, waits or None, floor, grid_frames)  # fmt: skip


@app.command("scale")
@cli_errors
def bench_scale(
    sizes: Annotated[str, typer.Option(help="route lengths N, comma-separated")] = "100000,1000000",
    n_features: Annotated[int, typer.Option("--d", help="descriptor size d")] = 512,
    frames_per_chunk: Annotated[int, typer.Option(
        help="paper presets: frames per chunk (n_chunks = N / this)")] = 10_000,
    region_length: Annotated[int, typer.Option(help="frames per regional scenery change")] = 2000,
    query_noise: Annotated[float, typer.Option(help="noise of the SYNTHETIC queries")] = 0.3,
    queries: Annotated[int, typer.Option(help="noisy queries of random frames")] = 2000,
    single: Annotated[int, typer.Option(help="single-query repetitions")] = 400,
    batch: Annotated[int, typer.Option(help="queries per batch call")] = 2000,
    exact_frames: Annotated[int, typer.Option(help="frames exact NN is measured on")] = 100_000,
    trainer: Annotated[str, typer.Option(help="paper presets: the trainer")] = "ridge",
    preset: Annotated[str, typer.Option(
        help="encoder preset: robust (the default, with its inverted file, beside FAISS IVF-SQ8 "
             "and HNSW) or residue; paper or ridge: the chunked mixed-radix code")] = "robust",
    hnsw_max: Annotated[int, typer.Option(help="largest N FAISS HNSW is built for")] = 200_000,
    sweep_noise: Annotated[str, typer.Option(
        help="default preset: query noises of the nprobe sweep, comma-separated")] = "0.3,4.0",
    also: Annotated[str, typer.Option(
        help="default preset: other presets trained and served on the same route, "
             "comma-separated (empty: none)")] = "drive",
    work_dir: Annotated[Path | None, typer.Option(help="where the route files go (temporary)")] = None,
    figure: Annotated[Path | None, typer.Option(help="PNG of query time (and bytes) against N")] = Path("query-time.png"),
    out: Annotated[Path, typer.Option(help="JSON output")] = Path("bench-scale.json"),
) -> None:
    """Train and serve SYNTHETIC maps up to 1M frames: time, peak RSS, artifact, load, latency,
    precision, beside exact NN (and for the default preset its flat scan and FAISS)."""
    work_dir = writable_dir(work_dir, "--work-dir")
    out = output_file(out, "--out")
    figure = None if figure is None else output_file(figure, "--figure")
    if preset in ("paper", "ridge"):
        from service.bench.scale_bench import run_scale_bench

        run_scale_bench([int(s) for s in sizes.split(",")], n_features, frames_per_chunk,
                        region_length, query_noise, queries, single, batch, exact_frames, trainer,
                        out, work_dir, figure, preset=preset)  # fmt: skip
        return
    from service.bench.scale_default import run_default_scale_bench

    run_default_scale_bench([int(s) for s in sizes.split(",")], n_features, region_length,
                            query_noise, queries, single, batch, exact_frames, out, preset,
                            work_dir, hnsw_max, figure,
                            sweep_noises=tuple(float(v) for v in sweep_noise.split(",") if v),
                            also=tuple(v for v in also.split(",") if v))  # fmt: skip


@app.command("scale-real")
@cli_errors
def bench_scale_real(
    reference: Annotated[Path, typer.Option(help="reference descriptors (.npy, N × d)")],
    query: Annotated[Path, typer.Option(help="query descriptors (.npy), query i ↔ frame i")],
    preset: Annotated[str, typer.Option(help="encoder preset (one class per frame)")] = "robust",
    single: Annotated[int, typer.Option(help="single-query repetitions")] = 200,
    label: Annotated[str, typer.Option(help="what the descriptors are, for the report")] = "",
    out: Annotated[Path, typer.Option(help="JSON output")] = Path("bench-scale-real.json"),
    nlist: Annotated[int | None, typer.Option(help="lists of the inverted file (default: ≈ 4√N)",
                                              min=1)] = None,  # fmt: skip
) -> None:
    """The default preset's inverted file on real descriptors: precision against its flat scan
    at the default nprobe and at larger shares of the lists."""
    out = output_file(out, "--out")
    from service.bench.scale_real import run_scale_real_bench

    run_scale_real_bench(reference, query, out, preset, single, label, nlist)


@app.command("growth")
@cli_errors
def bench_growth(
    sizes: Annotated[str, typer.Option(help="route lengths N, comma-separated")] = "10000,100000,1000000",
    n_features: Annotated[int, typer.Option("--d", help="descriptor size d")] = 512,
    region_length: Annotated[int, typer.Option(help="frames per regional scenery change")] = 2000,
    query_noise: Annotated[float, typer.Option(help="noise of the SYNTHETIC queries")] = 0.3,
    queries: Annotated[int, typer.Option(help="noisy queries per N")] = 1000,
    tolerance: Annotated[int, typer.Option(help="precision within ± frames")] = 5,
    target: Annotated[float, typer.Option(help="precision the cheapest setting must reach")] = 0.4,
    baseline_frames: Annotated[int, typer.Option(help="largest N exact NN and PQ are trained at")] = 100_000,
    trainer: Annotated[str, typer.Option()] = "ridge",
    work_dir: Annotated[Path | None, typer.Option(help="where the route file goes (temporary)")] = None,
    figure: Annotated[Path | None, typer.Option(help="PNG of storage and precision against N")] = Path("growth.png"),
    out: Annotated[Path, typer.Option(help="JSON output")] = Path("bench-growth.json"),
) -> None:
    """Storage and precision against N up to 1M SYNTHETIC frames for fixed settings and a fixed
    precision target, beside exact NN and PQ, with both power-law fits."""
    work_dir = writable_dir(work_dir, "--work-dir")
    out = output_file(out, "--out")
    figure = None if figure is None else output_file(figure, "--figure")
    from service.bench.growth_bench import run_growth_bench

    run_growth_bench([int(s) for s in sizes.split(",")], n_features, region_length, query_noise,
                     queries, tolerance, target, baseline_frames, trainer, out, figure, work_dir)  # fmt: skip


@app.command("sequence")
@cli_errors
def bench_sequence(
    sizes: Annotated[str, typer.Option(help="route lengths N timed, comma-separated")] = "10000,100000",
    repeats: Annotated[int, typer.Option(help="filter updates timed per N")] = 200,
    grid: Annotated[str, typer.Option(help="tuning grid on split A: small | tiny")] = "small",
    nordland: Annotated[bool, typer.Option(help="measure precision on Nordland if present")] = True,
    trainer: Annotated[str | None, typer.Option(help="gridplace trainer (default: the default config's)")] = None,
    out: Annotated[Path, typer.Option(help="JSON output")] = Path("bench-sequence.json"),
) -> None:
    """Sequence filter: per-frame cost beside the SeqSLAM filter; precision on Nordland
    (tuned on half A, reported on half B and the whole route) for exact NN and gridplace."""
    out = output_file(out, "--out")
    from service.bench.sequence_bench import GRIDS, run_sequence_bench
    from service.errors import InvalidParameterError

    if grid not in GRIDS:
        raise typer.BadParameter(f"choose one of {', '.join(GRIDS)}", param_hint="--grid")
    try:
        n_list = [int(s) for s in sizes.split(",") if s.strip()]
    except ValueError as exc:
        raise typer.BadParameter(f"not integers: {sizes!r}", param_hint="--sizes") from exc
    if not n_list or min(n_list) < 1 or repeats < 1:
        raise InvalidParameterError("--sizes and --repeats must be positive")
    from service.encoding import ModelParams

    params = ModelParams.parse(**({"trainer": trainer} if trainer else {}))
    run_sequence_bench(n_list, repeats, grid, nordland, params, out)


SummerRef = Annotated[Path, typer.Option(help="summer descriptors (.npy), frame-aligned with --qry")]
WinterQry = Annotated[Path, typer.Option(help="winter descriptors (.npy)")]
AppendedHalf = Annotated[int, typer.Option(help="first frame of the test half; frames before it are appended")]
JsonOut = Annotated[Path, typer.Option(help="JSON output")]


@app.command("append")
@cli_errors
def bench_append(ref: SummerRef, qry: WinterQry, half: AppendedHalf = 1788,
                 out: JsonOut = Path("bench-append.json"),
                 chunks: Annotated[int, typer.Option(min=1, help="chunks of the maps (1: unchunked)")] = 1,
                 ) -> None:  # fmt: skip
    """Append winter half A to a summer map (partial_fit) against training on both from
    scratch: time and precision on winter half B, beside the unappended map."""
    out = output_file(out, "--out")
    from service.bench.append_bench import run_append_bench

    run_append_bench(ref, qry, out, half, chunks)


@app.command("conditions")
@cli_errors
def bench_conditions(ref: SummerRef, qry: WinterQry, half: AppendedHalf = 1788,
                     out: JsonOut = Path("bench-conditions.json")) -> None:  # fmt: skip
    """Winter half A appended to a summer map tagged season=winter; winter half B queried
    with no condition, the condition named and inferred (single frames and drives)."""
    out = output_file(out, "--out")
    from service.bench.conditions_bench import run_conditions_bench

    run_conditions_bench(ref, qry, out, half)


from service.cli.bench_drive import bench_drive
from service.cli.bench_drive_scaling import bench_drive_scaling
from service.cli.bench_paper import bench_paper
from service.cli.bench_public_rss import bench_public_rss
from service.cli.bench_quality import bench_quality

app.command("paper")(bench_paper)
app.command("quality")(bench_quality)
app.command("drive")(bench_drive)
app.command("drive-scaling")(bench_drive_scaling)
app.command("public-rss")(bench_public_rss)

"""``gridplace bench paper``: the paper's experiments and the retrieval comparison, in one command."""

from __future__ import annotations

import os
import sys
from pathlib import Path
from typing import Annotated, Any

import typer
from rich.console import Console
from rich.markdown import Markdown
from rich.progress import Progress, SpinnerColumn, TextColumn, TimeElapsedColumn

from service.cli.paths import output_file, writable_dir

console = Console()


def _parse_shape(text: str | None) -> tuple[int, int] | None:
    if not text:
        return None
    try:
        h, w = (int(v) for v in text.lower().split("x"))
    except ValueError as exc:
        raise typer.BadParameter(
            f"image shape must look like 32x64 (rows x cols), got {text!r}"
        ) from exc
    return h, w


def bench_paper(
    dataset: Annotated[
        Path | None,
        typer.Option(
            help="dataset folder (reference/ and query/ images or .npy); "
            "omit for a clearly labelled SYNTHETIC route"
        ),
    ] = None,
    out: Annotated[Path, typer.Option(help="output folder (results.json, report.md, PNGs)")] = Path(
        "results"
    ),
    full: Annotated[
        bool,
        typer.Option(
            "--full/--quick",
            help="full paper-sized sweep (hours) instead of the quick budget (< 30 min on 2 cores)",
        ),
    ] = False,
    experiments: Annotated[
        str,
        typer.Option(help="comma-separated subset of storage,timing,patterns,chunking,retrieval"),
    ] = "storage,timing,patterns,chunking,retrieval",
    trainer: Annotated[
        str, typer.Option(help="trainer of the sweeps (ridge|logreg|svm|torch)")
    ] = "ridge",
    dtype: Annotated[str, typer.Option(help="storage dtype of every model")] = "float32",
    preprocess: Annotated[
        str, typer.Option(help="auto | patch | none (see the README of service.harness.datasets)")
    ] = "auto",
    patch: Annotated[int, typer.Option(help="patch size of SeqSLAM patch normalisation")] = 16,
    image_shape: Annotated[
        str | None,
        typer.Option(
            help="rows x cols of raw-pixel .npy frames when no images folder tells it, e.g. 32x64"
        ),
    ] = None,
    synthetic_frames: Annotated[int, typer.Option(help="N of the synthetic route")] = 2000,
    synthetic_features: Annotated[int, typer.Option(help="d of the synthetic route")] = 512,
    seed: Annotated[int, typer.Option()] = 0,
    torch_threads: Annotated[
        int, typer.Option(help="CPU threads of the torch trainer (0 = torch's default)")
    ] = 1,
    redraw: Annotated[
        bool,
        typer.Option(
            "--redraw",
            help="run nothing: re-make the PNGs and report.md in OUT from its results.json",
        ),
    ] = False,
    markdown: Annotated[
        Path | None,
        typer.Option(
            help="also write the report here, figures linked relative to it "
            "(e.g. docs/RESULTS.md with --out docs/results)"
        ),
    ] = None,
) -> None:
    """Storage scaling, training/query time, precision vs k, chunking at scale, and gridplace
    against exact NN and PQ — JSON, a Markdown report and PNG plots in OUT."""
    from service.errors import GridplaceError
    from service.harness import BenchConfig, load_dataset, run_paper, synthetic_dataset
    from service.harness.runner import redraw as redraw_results

    try:
        if not redraw:  # its folder is written: a file in the way is refused before any work
            writable_dir(out, "--out")
        if markdown is not None:
            markdown = output_file(markdown, "--markdown")
        if redraw:
            results = redraw_results(out)
            _finish(results, out, markdown)
            return
        names = tuple(e.strip() for e in experiments.split(",") if e.strip())
        overrides = {"experiments": names, "trainer": trainer, "dtype": dtype, "seed": seed,
                     "torch_threads": torch_threads or None}  # fmt: skip
        cfg = BenchConfig.full(**overrides) if full else BenchConfig.quick(**overrides)
        if dataset is None:
            ds = synthetic_dataset(synthetic_frames, synthetic_features, seed=seed)
            console.print(f"[yellow]no --dataset: using {ds.label}[/yellow]")
        else:
            ds = load_dataset(dataset, preprocess=preprocess, patch=patch,
                              image_shape=_parse_shape(image_shape))  # fmt: skip
        console.print(f"dataset: {ds.label}; budget: {cfg.preset}; experiments: {cfg.experiments}")
        with Progress(SpinnerColumn(), TextColumn("{task.description}"), TimeElapsedColumn(),
                      console=console, transient=True) as bar:  # fmt: skip
            task = bar.add_task("starting", total=None)
            results = run_paper(ds, out, cfg, argv=["gridplace", *sys.argv[1:]],
                                progress=lambda msg: bar.update(task, description=msg))  # fmt: skip
    except GridplaceError as exc:
        console.print(f"[red]error:[/red] {exc}")
        raise typer.Exit(2) from exc
    _finish(results, out, markdown)


def _finish(results: dict[str, Any], out: Path, markdown: Path | None) -> None:
    from service.harness.report import render
    from service.harness.runner import write_atomic

    console.print(Markdown(render(results)))
    if markdown is not None:
        prefix = Path(os.path.relpath(out.resolve(), markdown.resolve().parent)).as_posix()
        write_atomic(markdown, render(results, figure_prefix=f"{prefix}/"))
        console.print(f"wrote {markdown}")
    console.print(f"wrote {out}/results.json, {out}/report.md and {len(results['figures'])} PNGs; "
                  f"the run took {results['elapsed_seconds'] / 60:.1f} min")  # fmt: skip

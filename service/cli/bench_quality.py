"""``gridplace bench quality``: every method on the same descriptors across conditions."""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Annotated, Any

import typer
from rich.console import Console

from service.cli.errors import cli_errors
from service.cli.paths import output_file

console = Console()


@cli_errors
def bench_quality(
    dataset: Annotated[Path | None, typer.Argument(
        help="dataset folder: reference/ + query/ PNG folders and/or reference.npy + query.npy "
             "(pixels are patch-normalised like `gridplace extract --extractor patchnorm`)",
    )] = None,
    reference: Annotated[list[Path] | None, typer.Option(
        "--reference", help="pre-extracted reference descriptors .npy (repeatable, with --query)",
    )] = None,
    query: Annotated[list[Path] | None, typer.Option(
        "--query", help="query descriptors .npy of the same route, one per --reference")] = None,
    ground_truth: Annotated[Path | None, typer.Option(
        help="int .npy: query i -> reference index, for the --reference/--query pairs "
             "(default: frame-aligned)")] = None,
    protocols: Annotated[str, typer.Option(
        help="comma-separated: cross (a: reference -> query traversal), "
             "multi (b: reference + half the query traversal -> the other half)")] = "cross,multi",
    methods: Annotated[str, typer.Option(
        help="'all' or comma-separated method names / families (exact_nn, pq, yu, gridplace, "
             "exact_nn_projected, pq-m16, ridge, paper, ...)")] = "all",
    yu_trainer: Annotated[str, typer.Option(help="trainer of Yu et al.'s encoder")] = "ridge",
    patch: Annotated[int, typer.Option(help="patchnorm patch side for pixel datasets")] = 16,
    filter_params: Annotated[list[str] | None, typer.Option(
        "--filter", metavar="KEY=VALUE", help="sequence filter parameter (default: the filter's "
                                              "defaults, tuned on half A)")] = None,
    out: Annotated[Path, typer.Option(help="JSON output")] = Path("bench-quality.json"),
    figure: Annotated[Path | None, typer.Option(
        help="PNG of precision against bytes (none if omitted)")] = None,
    markdown: Annotated[Path | None, typer.Option(
        help="also write the tables as Markdown here")] = None,
    merge: Annotated[list[Path] | None, typer.Option(
        "--merge", help="run nothing: merge these reports (repeatable; a method in several "
                        "keeps its last run; --methods keeps only those) into --out and --figure",
    )] = None,
) -> None:
    """Precision (±0/2/5/10, single frame and sequence) and storage of exact NN, PQ, Yu et al.
    and gridplace configurations on the same descriptors: reference -> query traversal and
    multi-traversal; half A of the drive is validation, half B test."""
    out = output_file(out, "--out")
    figure = None if figure is None else output_file(figure, "--figure")
    markdown = None if markdown is None else output_file(markdown, "--markdown")
    from service.bench.quality_bench import merge_reports
    from service.bench.quality_report import markdown_tables, plot_frontier, print_report

    if merge:
        report = merge_reports([json.loads(p.read_text()) for p in merge], methods)
        out.write_text(json.dumps(report, indent=2))
        print_report(report, console)
        console.print(f"wrote {out}")
    else:
        report = _run(dataset, reference, query, ground_truth, protocols, methods, yu_trainer,
                      patch, filter_params, out)  # fmt: skip
    if figure is not None:
        console.print(f"wrote {plot_frontier(report, figure)}")
    if markdown is not None:
        markdown.write_text(markdown_tables(report))
        console.print(f"wrote {markdown}")


def _run(dataset: Path | None, reference: list[Path] | None, query: list[Path] | None,
         ground_truth: Path | None, protocols: str, methods: str, yu_trainer: str, patch: int,
         filter_params: list[str] | None, out: Path) -> dict[str, Any]:  # fmt: skip
    from service.bench.quality_bench import load_sets, run_quality_bench
    from service.bench.quality_report import print_report
    from service.cli.model_commands import sequence_config
    from service.errors import InvalidParameterError

    refs, qrys = reference or [], query or []
    if len(refs) != len(qrys):
        raise InvalidParameterError("give one --query per --reference")
    sets = load_sets(dataset, list(zip(refs, qrys, strict=True)), patch, ground_truth)
    chosen = tuple(p.strip() for p in protocols.split(",") if p.strip())
    config = sequence_config(filter_params)
    with console.status("starting") as status:
        report = run_quality_bench(sets, chosen, methods, config, out,
                                   progress=lambda m: status.update(m), yu_trainer=yu_trainer,
                                   argv=["gridplace", *sys.argv[1:]])  # fmt: skip
    print_report(report, console)
    console.print(f"wrote {out} ({report['elapsed_seconds'] / 60:.1f} min)")
    return report

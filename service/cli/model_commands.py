"""``gridplace train | localize | evaluate | demo``: the library on ``.npy`` files."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated, Any

import numpy as np
import typer

from service.cli.errors import cli_errors
from service.cli.console import cli_console, plural
from service.cli.model_reading import preset_line, storage_line
from service.cli.fit_progress import fit_title, fit_with_progress
from service.cli.train_tuning import (
    BudgetOpt,
    TargetOpt,
    ValidationOpt,
    ValidationToleranceOpt,
    ValidationTruthOpt,
    tune,
    wants_tuning,
)
from service.encoding import (
    ModelParams,
    build_model,
    check_new_artifact_dir,
    default_trainer,
    load_model,
    load_npy,
    save_model,
)
from service.encoding.adaptation import AdaptationConfig, adapt_drive, adapts
from service.encoding.evaluation import evaluate as evaluate_model
from service.encoding.phases import parse_periods
from service.encoding.presets import DEFAULT_PRESET, describe_presets
from service.cli.odometry_options import OdometryOpt, SpacingOpt, odometry_for
from service.encoding.sequence import SequenceConfig, sequence_localize
from service.encoding.traversals import as_traversals
from service.encoding.validation import check_descriptors
from service.errors import InvalidParameterError

console = cli_console()


@cli_errors
def train(
    references: Annotated[list[Path], typer.Argument(
        metavar="REFERENCE", help=".npy descriptors, rows in route order; several files are traversals of the same "
        "places (frame-aligned, or with --places)", show_default=False)],
    out: Annotated[Path, typer.Option("--out", "-o", help="new artifact directory (must not exist)")],
    places: Annotated[list[Path] | None, typer.Option(
        "--places", help="int .npy: the place (0..N-1) of every row of one descriptor file; "
        "give it once per file, in the files' order", show_default=False)] = None,
    preset: Annotated[str | None, typer.Option(
        help=f"encoder preset: {describe_presets()}. Without it: {DEFAULT_PRESET}, or paper when "
        "an option of the paper's code is given (--patterns, --periods, --rho, --gamma, --C, "
        "--code mixed_radix, a --trainer other than prototype); options override the preset's "
        "fields", show_default=False)] = None,
    patterns: Annotated[int | None, typer.Option("--patterns", "-k", help="number of encoders k",
                                                 show_default=False)] = None,
    periods: Annotated[str | None, typer.Option(help="explicit periods, e.g. 60,60")] = None,
    rho: Annotated[float | None, typer.Option(help="fraction of columns per encoder",
                                              show_default=False)] = None,
    gamma: Annotated[float | None, typer.Option(help="L1 bound (default sqrt(d'))")] = None,
    trainer: Annotated[str | None, typer.Option(
        help=f"(default: {default_trainer()}) logreg (the paper's) | svm | ridge | torch | "
        "prototype",
        show_default=False)] = None,
    c: Annotated[float | None, typer.Option("--C", help="inverse regularisation",
                                            show_default=False)] = None,
    decode: Annotated[str, typer.Option(help="joint | argmax")] = "joint",
    dtype: Annotated[str | None, typer.Option(help="float64 | float32 | float16 | int8 | binary (sign bits: class templates)",
                                              show_default=False)] = None,
    code: Annotated[str | None, typer.Option(help="mixed_radix | residue",
                                             show_default=False)] = None,
    components: Annotated[int | None, typer.Option(
        "--components", help="PCA projection width (0 = no projection)",
        show_default=False)] = None,
    chunks: Annotated[int, typer.Option(help="number of chunks (1 = none)")] = 1,
    chunk_rho: Annotated[float | None, typer.Option(help="rho of the chunk classifier")] = None,
    top_chunks: Annotated[int, typer.Option(help="chunks decoded per query")] = 2,
    n_jobs: Annotated[int, typer.Option(help="chunk processes, or one-vs-rest threads without chunks (-1 = all)")] = 1,
    budget_bytes: BudgetOpt = None,
    target_precision: TargetOpt = None,
    validation: ValidationOpt = None,
    validation_truth: ValidationTruthOpt = None,
    validation_tolerance: ValidationToleranceOpt = 5,
) -> None:
    """Train a model on a route (one or several traversals of it) and save it as a new
    artifact (no options: the default preset). With --budget-bytes and/or --target-precision
    the configuration is chosen on a validation split first (it replaces the encoder options)."""
    given = {"encoder_preset": preset, "n_patterns": patterns, "rho": rho, "trainer": trainer,
             "C": c, "dtype": dtype, "code": code}  # fmt: skip
    chosen: dict[str, object] = {k: v for k, v in given.items() if v is not None}
    if components is not None:
        chosen["n_components"] = components or None
    explicit = {**chosen, "periods": parse_periods(periods, "--periods"), "gamma": gamma}
    params = ModelParams.parse(decode=decode, n_chunks=chunks, chunk_rho=chunk_rho,
                               top_chunks=top_chunks, n_jobs=n_jobs, **explicit)  # fmt: skip
    check_new_artifact_dir(out)  # before minutes of training, not after
    if places and len(places) != len(references):
        raise InvalidParameterError(
            f"{len(references)} descriptor file(s) need {len(references)} --places file(s) "
            f"(one per file, in order), got {len(places)}"
        )
    arrays = [load_npy(path) for path in references]
    index = [load_npy(path) for path in places] if places else None
    if len(arrays) == 1:  # one file: messages name it
        arrays = [check_descriptors(arrays[0], min_rows=1 if index else 2, what=str(references[0]))]
    tuning = None
    if wants_tuning(budget_bytes, target_precision):
        params, tuning = tune(params, arrays, index, validation, validation_truth, budget_bytes,
                              target_precision, validation_tolerance, console)  # fmt: skip
    tr = as_traversals(arrays, index, names=[p.name for p in references])
    model = build_model(params)
    title = fit_title(model, tr.n_places, tr.n_traversals)
    seconds = fit_with_progress(model, tr, console, title)
    source = str(references[0]) if len(references) == 1 else [str(p) for p in references]
    extra: dict[str, Any] = {"train_seconds": seconds, "source": source}
    if tuning is not None:
        extra["autotune"] = tuning.to_dict()
    extra["encoder_preset"] = params.encoder_preset
    manifest = save_model(model, out, extra=extra)
    console.print(
        f"saved {out}: {model.kind} {preset_line(params, explicit)} "
        f"N={model.n_frames_} d={model.n_features_in_} traversals={model.n_traversals_} "
        f"in {seconds:.1f}s; {storage_line(model, manifest['footprint'])}",
        highlight=False,
    )


SequenceOpt = Annotated[
    bool, typer.Option("--sequence", help="the query rows are one drive, in order: sequence filter")
]
FilterOpt = Annotated[
    list[str] | None,
    typer.Option(
        "--filter", metavar="KEY=VALUE",
        help="a sequence filter parameter, repeatable (e.g. emission_scale=0.2, reverse=true)",
    ),
]  # fmt: skip


AdaptOpt = Annotated[
    bool | None,
    typer.Option(
        "--adapt/--no-adapt",
        help="standardise the query rows by the running statistics of the rows before them "
             "(appearance adaptation: one camera's frames, in row order) [default: on when the "
             "model keeps route statistics]",
        show_default=False,
    ),
]  # fmt: skip


def adaptation_for(model: Any, adapt: bool | None) -> AdaptationConfig | None:
    """``--adapt/--no-adapt`` for ``model`` (on by default; ``--adapt`` needs route statistics)."""
    return AdaptationConfig() if adapts(model, adapt, default=True) else None


def sequence_config(items: list[str] | None) -> SequenceConfig:
    """``--filter KEY=VALUE`` options as a validated filter configuration."""
    given: dict[str, str] = {}
    for item in items or []:
        key, sep, value = item.partition("=")
        if not sep or not key:
            raise InvalidParameterError(f"--filter must be KEY=VALUE, got {item!r}")
        given[key.strip()] = value.strip()
    return SequenceConfig.parse(**given)


@cli_errors
def localize(
    model_dir: Annotated[Path, typer.Argument(help="artifact directory")],
    queries: Annotated[Path, typer.Argument(help=".npy query descriptors")],
    out: Annotated[Path | None, typer.Option("--out", "-o", help="write indices (.npy)")] = None,
    confidence_out: Annotated[Path | None, typer.Option(help="write confidences (.npy)")] = None,
    sequence: SequenceOpt = False,
    filter_params: FilterOpt = None,
    adapt: AdaptOpt = None,
    odometry: OdometryOpt = None,
    odometry_spacing: SpacingOpt = None,
) -> None:
    """Predict the frame index of every query row (with --sequence: the filtered estimates)."""
    if filter_params and not sequence:
        raise InvalidParameterError("--filter needs --sequence")
    if odometry is not None and not sequence:
        raise InvalidParameterError("--odometry needs --sequence")
    config = sequence_config(filter_params) if sequence else None
    model = load_model(model_dir)
    Q = check_descriptors(load_npy(queries), n_features=model.n_features_in_, what=str(queries))
    adaptation = adaptation_for(model, adapt)
    if adaptation is not None:
        Q = adapt_drive(model, Q, adaptation)
    if config is not None:
        u = odometry_for(odometry, Q.shape[0], odometry_spacing)
        track = sequence_localize(model, Q, config, odometry=u)
        index, confidence = track.index, track.confidence
    else:
        loc = model.localize(Q)
        index, confidence = loc.index, loc.confidence
    if out is not None:
        np.save(out, index)
    if confidence_out is not None:
        np.save(confidence_out, confidence)
    if out is None:
        for i, c in zip(index, confidence, strict=True):
            typer.echo(f"{int(i)}\t{float(c):.4f}")


@cli_errors
def evaluate(
    model_dir: Annotated[Path, typer.Argument(help="artifact directory")],
    queries: Annotated[Path, typer.Argument(help=".npy query descriptors")],
    tolerance: Annotated[int, typer.Option(min=0, help="frames of tolerance (≥ 0)")] = 0,
    ground_truth: Annotated[Path | None, typer.Option(help="int .npy: query i -> frame")] = None,
    as_json: Annotated[bool, typer.Option("--json", help="print JSON")] = False,
    sequence: SequenceOpt = False,
    filter_params: FilterOpt = None,
    adapt: AdaptOpt = None,
    odometry: OdometryOpt = None,
    odometry_spacing: SpacingOpt = None,
) -> None:
    """Precision within a tolerance, query time and storage of a saved model (with --sequence
    also the sequence filter's precision, the query file being one drive in row order)."""
    if filter_params and not sequence:
        raise InvalidParameterError("--filter needs --sequence")
    if odometry is not None and not sequence:
        raise InvalidParameterError("--odometry needs --sequence")
    config = sequence_config(filter_params) if sequence else None
    model = load_model(model_dir)
    truth = load_npy(ground_truth) if ground_truth is not None else None
    Q = check_descriptors(load_npy(queries), n_features=model.n_features_in_, what=str(queries))
    u = odometry_for(odometry, Q.shape[0], odometry_spacing)
    result = evaluate_model(model, Q, truth, tolerance, sequence=config,
                            adaptation=adaptation_for(model, adapt), odometry=u)  # fmt: skip
    if as_json:
        typer.echo(json.dumps(result))
        return
    adapted = result["adaptation"]
    console.print(
        f"precision@{tolerance} (within ±{tolerance} frames): {result['precision']:.4f} on "
        f"{plural(result['n'], 'query', 'queries')}; {storage_line(model, result['footprint'])}; "
        f"{result['query_seconds_per_descriptor'] * 1e6:.1f} µs/query; appearance adaptation "
        + (f"on (alpha {adapted['alpha']:g}; --no-adapt: off)" if adapted else "off"),
        highlight=False,
    )
    if config is not None:
        seq = result["sequence"]
        console.print(
            f"sequence precision@{tolerance}: {result['sequence_precision']:.4f} "
            f"(the queries as one drive; {seq['seconds_per_frame'] * 1e6:.0f} µs/frame)"
        )


def register(app: typer.Typer) -> None:
    app.command()(train)
    app.command()(localize)
    app.command()(evaluate)

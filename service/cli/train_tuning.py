"""``gridplace train --budget-bytes N / --target-precision P``: the configuration chosen on a
validation split (:func:`service.encoding.autotune.autotune`), never on test frames.

The validation split is ``--validation Q.npy`` (queries of the route, frame-aligned unless
``--validation-truth T.npy`` gives each query's place), or, without it and with two or more
traversals, the last traversal held out: the candidates train on the others and are scored
on it, and the chosen configuration is then trained on every traversal.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any

import numpy as np
import typer
from rich.console import Console
from rich.markup import escape
from rich.table import Table

from service.cli.console import print_table
from service.encoding import ModelParams, load_npy
from service.encoding.autotune import AutotuneResult, autotune, default_candidates
from service.encoding.traversals import as_traversals
from service.encoding.validation import check_descriptors
from service.errors import InvalidParameterError

BudgetOpt = Annotated[int | None, typer.Option(
    help="choose the configuration: the most precise whose artifact fits this many bytes, "
         "measured on a validation split (--validation)", show_default=False)]
TargetOpt = Annotated[float | None, typer.Option(
    help="choose the smallest configuration whose validation precision (0-1, within "
         "--validation-tolerance frames) reaches this", show_default=False)]
ValidationOpt = Annotated[Path | None, typer.Option(
    help="validation queries .npy of this route for --budget-bytes/--target-precision "
         "(default: hold out the last traversal)", show_default=False)]
ValidationTruthOpt = Annotated[Path | None, typer.Option(
    help="int .npy: the place of each --validation query (default: frame-aligned)",
    show_default=False)]
ValidationToleranceOpt = Annotated[int, typer.Option(
    min=0, help="frames of tolerance of the validation precision")]

# fields of the user's parameters kept on every candidate (how to train, not what)
KEPT_FIELDS = ("n_chunks", "chunk_rho", "top_chunks", "n_jobs", "random_state")


def wants_tuning(budget_bytes: int | None, target_precision: float | None) -> bool:
    return budget_bytes is not None or target_precision is not None


def _validation_split(arrays: list[np.ndarray], index: list[np.ndarray] | None,
                      validation: Path | None, validation_truth: Path | None,
                      ) -> tuple[Any, np.ndarray, np.ndarray, str]:  # fmt: skip
    """``(training traversals, validation queries, their places, description)``."""
    if validation is not None:
        Q = check_descriptors(load_npy(validation), n_features=arrays[0].shape[1],
                              what=str(validation))  # fmt: skip
        truth = (load_npy(validation_truth) if validation_truth is not None
                 else np.arange(Q.shape[0]))  # fmt: skip
        return as_traversals(arrays, index), Q, np.asarray(truth), str(validation)
    if validation_truth is not None:
        raise InvalidParameterError("--validation-truth needs --validation")
    if len(arrays) < 2:
        raise InvalidParameterError(
            "--budget-bytes/--target-precision choose on a validation split: give "
            "--validation Q.npy (queries with known places), or two or more traversals "
            "(the last one is held out)"
        )
    held = arrays[-1]
    truth = index[-1] if index else np.arange(held.shape[0])
    train = as_traversals(arrays[:-1], index[:-1] if index else None)
    return train, check_descriptors(held, what="held-out traversal"), np.asarray(truth), (
        f"the last traversal ({held.shape[0]} rows), held out")  # fmt: skip


def tune(
    params: ModelParams,
    arrays: list[np.ndarray],
    index: list[np.ndarray] | None,
    validation: Path | None,
    validation_truth: Path | None,
    budget_bytes: int | None,
    target_precision: float | None,
    tolerance: int,
    console: Console,
) -> tuple[ModelParams, AutotuneResult]:
    """The chosen parameters (the user's ``KEPT_FIELDS`` on every candidate), after printing
    every candidate's validation precision and bytes."""
    train, Q, truth, where = _validation_split(arrays, index, validation, validation_truth)
    keep = {k: getattr(params, k) for k in KEPT_FIELDS}
    cands = [type(c)(c.name, c.params.model_copy(update=keep)) for c in default_candidates()]
    with console.status("tuning") as status:
        result = autotune(train, Q, truth, cands, budget_bytes, target_precision, tolerance,
                          progress=lambda name, i, n: status.update(
                              escape(f"tuning on {where}: {name} ({i + 1}/{n})")))  # fmt: skip
    table = Table(title=f"candidates on {where}: precision within ±{tolerance} frames")
    for col in ("candidate", "precision", "actual bytes", "fits", "chosen"):
        table.add_column(col)
    for c in sorted(result.candidates, key=lambda c: c.actual_bytes):
        table.add_row(escape(c.name), f"{c.precision:.3f}", str(c.actual_bytes),
                      "yes" if c.within_budget else "no",
                      "←" if c is result.chosen else "")  # fmt: skip
    print_table(console, table)
    console.print(f"chose {escape(result.chosen.name)}: {escape(result.reason)}")
    return result.params, result

"""``gridplace demo``: the main job end to end on the embedded default (no Redis, no Docker)."""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Annotated

import numpy as np
import typer
from rich.console import Console
from rich.table import Table

from service.bench.data import nordland
from service.cli.errors import cli_errors
from service.encoding import ExactNN, PhaseEncoder, load_model, save_model
from service.encoding.evaluation import evaluate
from service.encoding.synthetic import smooth_route

console = Console()


@cli_errors
def demo(
    out: Annotated[Path, typer.Option(help="where the trained artifact is written")] = Path(
        "gridplace-data/demo"
    ),
    trainer: Annotated[str, typer.Option(help="logreg | svm | ridge | torch")] = "ridge",
    patterns: Annotated[int, typer.Option("--patterns", "-k")] = 2,
    rho: Annotated[float, typer.Option()] = 0.5,
) -> None:
    """Train on the Nordland route (summer), save, reload, and localize winter queries."""
    route = nordland()
    if route is None:
        synth = smooth_route(3000, 512, seed=0)
        reference, query, label = synth.reference, synth.query, synth.label
    else:
        reference, query, label = route.reference, route.query, route.label
    console.print(f"[bold]dataset[/]: {label}; N={reference.shape[0]}, d={reference.shape[1]}")
    start = time.perf_counter()
    model = PhaseEncoder(n_patterns=patterns, rho=rho, trainer=trainer).fit(reference)
    train_s = time.perf_counter() - start
    stamp = time.strftime("%Y%m%d-%H%M%S")
    path = out / f"phase-{trainer}-{stamp}"
    save_model(model, path, extra={"train_seconds": train_s, "dataset": label})
    model = load_model(path)  # answer from the verified artifact, as the server does
    nn = ExactNN().fit(reference)
    table = Table(title=f"gridplace demo ({label})")
    for col in ("model", "condition", "P@0", "P@1", "P@5", "storage bytes", "µs/query"):
        table.add_column(col)
    results = {}
    for name, m in (("gridplace", model), ("exact NN", nn)):
        for cond, Q in (("identical", reference), ("cross-season", query)):
            r = evaluate(m, Q, tolerance=5)
            results[f"{name}/{cond}"] = r
            pa = r["precision_at"]
            table.add_row(name, cond, f"{pa['0']:.3f}", f"{pa['1']:.3f}", f"{pa['5']:.3f}",
                          str(r["footprint_bytes"]),
                          f"{r['query_seconds_per_descriptor'] * 1e6:.0f}")  # fmt: skip
    console.print(table)
    console.print(f"trained in {train_s:.1f}s (periods {list(model.periods_)}); artifact: {path}")
    (path.parent / f"{path.name}.results.json").write_text(
        json.dumps({k: {kk: v for kk, v in r.items() if kk != "footprint"} for k, r in results.items()},
                   indent=2, default=lambda o: o.item() if isinstance(o, np.generic) else str(o))
    )


def register(app: typer.Typer) -> None:
    app.command()(demo)

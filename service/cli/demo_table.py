"""The demo's table: the trained model beside exact NN in its own projected space and exact
NN on the descriptors, in every condition the demo measures."""

from __future__ import annotations

from typing import Any

from rich.console import Console
from rich.table import Table

from service.cli.console import print_table
from service.cli.demo_data import DemoData
from service.cli.demo_reading import TOLERANCE
from service.encoding import ExactNN
from service.encoding.adaptation import AppearanceAdapter
from service.encoding.base import PlaceRecognizer
from service.encoding.evaluation import evaluate
from service.encoding.sequence import SequenceConfig
from service.harness.projected_nn import ProjectedNN

CONDITIONS = {  # result key → what the table calls it
    "identical": "identical",
    "cross-season as sent": "cross-season, as sent",
    "cross-season": "cross-season, adapted",
    "cross-season drive": "as a drive, adapted",
}
CAPTION = ("P@k: the fraction of query frames answered within ±k frames of their true frame. "
           "Storage: the bytes each model stores.")  # fmt: skip


def _models(model: PlaceRecognizer, preset: str | None,
            data: DemoData) -> list[tuple[str, str, Any]]:  # fmt: skip
    """``(result key, table label, fitted model)`` of every model in the table."""
    out: list[tuple[str, str, Any]] = [("gridplace", f"gridplace ({preset or model.kind})", model)]
    front = getattr(model, "normalizer_", None)
    projection = getattr(front, "projection", None)
    if projection is not None:  # the same front-end, every projected frame kept (float32)
        width = int(projection.n_components)
        same = ProjectedNN(n_components=width, whiten_power=float(getattr(model, "whiten_power")))
        out.append(("nn-pca", f"nn-pca{width} (exact NN, same space)", same.fit(data.reference)))
    out.append(("exact NN", "exact NN", ExactNN().fit(data.reference)))
    return out


def evaluate_all(console: Console, model: PlaceRecognizer, preset: str | None,
                 data: DemoData) -> dict[str, dict[str, Any]]:  # fmt: skip
    """Every model on the training frames, on the other season frame by frame as sent and
    adapted (appearance adaptation from the reference's statistics, as the server does for
    drives), and adapted as one drive through the sequence filter (its default parameters);
    prints the table and returns ``"<model>/<condition>"`` → the evaluation."""
    adapted_query = AppearanceAdapter.for_reference(data.reference).transform(data.query)
    table = Table(title=f"gridplace demo ({data.label})", caption=CAPTION)
    for col in ("model", "condition", "P@0", "P@1", "P@5", "storage bytes", "µs/query"):
        table.add_column(col)
    results: dict[str, dict[str, Any]] = {}
    for key, label, m in _models(model, preset, data):
        same = evaluate(m, data.reference, tolerance=TOLERANCE)
        sent = evaluate(m, data.query, tolerance=TOLERANCE)
        cross = evaluate(m, adapted_query, tolerance=TOLERANCE, sequence=SequenceConfig())
        per_frame = cross["sequence"]["seconds_per_frame"]
        drive = {**cross, "precision_at": cross["sequence_precision_at"],
                 "query_seconds_per_descriptor": per_frame}  # fmt: skip
        conditions = {"identical": same, "cross-season as sent": sent, "cross-season": cross,
                      "cross-season drive": drive}  # fmt: skip
        for cond, r in conditions.items():
            results[f"{key}/{cond}"] = {**r, "n_components": getattr(m, "n_components", None)}
            pa = r["precision_at"]
            table.add_row(label, CONDITIONS[cond], f"{pa['0']:.3f}", f"{pa['1']:.3f}",
                          f"{pa['5']:.3f}", f"{r['footprint_bytes']:,}",
                          f"{r['query_seconds_per_descriptor'] * 1e6:.0f}")  # fmt: skip
        table.add_section()
    print_table(console, table)
    return results

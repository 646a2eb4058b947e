"""A rich progress bar that follows a fit's ``progress(detail, done, total)`` reports."""

from __future__ import annotations

import time
from typing import Any

import numpy as np
from rich.console import Console
from rich.progress import (
    BarColumn,
    Progress,
    TaskProgressColumn,
    TextColumn,
    TimeElapsedColumn,
    TimeRemainingColumn,
)

from service.encoding import ChunkedPlaceEncoder, PhaseEncoder
from service.encoding.traversals import Traversals


def fit_with_progress(model: PhaseEncoder | ChunkedPlaceEncoder, X: np.ndarray | Traversals,
                      console: Console, title: str) -> float:  # fmt: skip
    """Fit ``model`` on ``X`` (one route, or validated traversals of it) under a progress
    bar (per class of every digit); returns the seconds the fit took. The bar is removed
    when the fit ends."""
    columns = (TextColumn("{task.description}"), BarColumn(), TaskProgressColumn(),
               TimeElapsedColumn(), TimeRemainingColumn())  # fmt: skip
    with Progress(*columns, console=console, transient=True) as bar:
        task = bar.add_task(title, total=None)

        def report(detail: str, done: int, total: int) -> None:
            bar.update(task, description=f"{title} · {detail}", completed=done, total=total)

        start = time.perf_counter()
        model.fit(X, progress=report)
        return time.perf_counter() - start


def fit_title(model: Any, n_frames: int, n_traversals: int = 1) -> str:
    several = f" × {n_traversals} traversals" if n_traversals > 1 else ""
    return f"training {model.kind} ({model.trainer}) on {n_frames} frames{several}"

"""What every output says about the run: date, machine, software, command."""

from __future__ import annotations

import os
import platform
import subprocess
import sys
from datetime import UTC, datetime
from importlib import metadata
from pathlib import Path
from typing import Any


def _version(dist: str) -> str | None:
    try:
        return metadata.version(dist)
    except metadata.PackageNotFoundError:
        return None


def _git_commit() -> str | None:
    here = Path(__file__).resolve().parents[2]
    try:
        out = subprocess.run(
            ["git", "rev-parse", "--short", "HEAD"], cwd=here, capture_output=True, text=True,
            timeout=5, check=False,
        )  # fmt: skip
    except (OSError, subprocess.SubprocessError):
        return None
    return out.stdout.strip() or None


def usable_cores() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - not on Linux
        return os.cpu_count() or 1


def set_torch_threads(n: int | None) -> int | None:
    """Bound torch's CPU threads (``None`` keeps its default); returns the count in force,
    or ``None`` when torch is not installed."""
    try:
        import torch
    except ImportError:
        return None
    if n is not None:
        torch.set_num_threads(max(1, int(n)))
    return int(torch.get_num_threads())


def run_context(argv: list[str] | None = None) -> dict[str, Any]:
    """JSON-ready description of this run."""
    return {
        "date": datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC"),
        "machine": {
            "cores": usable_cores(),
            "cpu_count": os.cpu_count(),
            "platform": platform.platform(),
            "processor": platform.processor() or platform.machine(),
        },
        "software": {
            "python": sys.version.split()[0],
            **{
                name: _version(name)
                for name in ("numpy", "scipy", "scikit-learn", "torch", "faiss-cpu", "gridplace")
            },
        },
        "git_commit": _git_commit(),
        "command": " ".join(argv if argv is not None else sys.argv),
    }


def footer(context: dict[str, Any], dataset: dict[str, Any]) -> str:
    """One line for the bottom of every figure."""
    synth = "SYNTHETIC — " if dataset.get("synthetic") else ""
    return (
        f"{synth}{dataset['name']} (N={dataset['N']}, d={dataset['d']}) · "
        f"{context['machine']['cores']} cores · {context['date']} · gridplace {context['git_commit']}"
    )

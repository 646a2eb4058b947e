"""Run the selected experiments on one dataset and write JSON, Markdown and PNGs."""

from __future__ import annotations

import json
import os
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from service.errors import InvalidInputError
from service.harness import plots
from service.harness.config import BenchConfig
from service.harness.context import footer, run_context, set_torch_threads
from service.harness.datasets import Dataset
from service.harness.exp_chunking import run_chunking
from service.harness.exp_patterns import run_patterns
from service.harness.exp_retrieval import run_retrieval
from service.harness.exp_storage import run_storage
from service.harness.exp_timing import run_timing
from service.harness.report import render

RESULTS_JSON = "results.json"
REPORT_MD = "report.md"


PLOTTERS: dict[str, Callable[[dict[str, Any], str, str, Path], Path]] = {
    "storage": plots.plot_storage,
    "timing": plots.plot_timing,
    "patterns": plots.plot_patterns,
    "chunking": plots.plot_chunking,
    "retrieval": plots.plot_retrieval,
}


def _meta(name: str, cfg: dict[str, Any], dataset: dict[str, Any], res: dict[str, Any]) -> str:
    """The parameters a figure states in its title (from the JSON config, so redraws match)."""
    common = f"trainer {cfg['trainer']}, {cfg['dtype']}"
    if name == "storage":
        return f"ρ∈{list(cfg['storage_rhos'])}, k∈{list(cfg['storage_ks'])}, {common}"
    if name == "timing":
        return f"k={cfg['timing_k']}, gridplace ρ={cfg['timing_rho']}, Yu ρ=1, {cfg['dtype']}"
    if name == "patterns":
        return f"N={dataset['N']}, gridplace ρ={cfg['pattern_rho']}, Yu ρ=1, {common}"
    if name == "chunking":
        return (f"N={res['dataset']['N']}, d={res['dataset']['d']}, {cfg['chunk_n_chunks']} "
                f"chunks, k={cfg['chunk_k']}, ρ={cfg['chunk_rho']}, {common}")  # fmt: skip
    return f"N={dataset['N']}, {common}"


def draw(results: dict[str, Any], name: str, out: Path) -> str:
    """Draw experiment ``name`` of ``results`` into ``out``; returns the file name."""
    res = results["experiments"][name]
    shown = res.get("dataset", results["dataset"])
    fig = f"{name}.png"
    meta = _meta(name, results["config"], results["dataset"], res)
    PLOTTERS[name](res, meta, footer(results["context"], shown), out / fig)
    return fig


def redraw(out: Path) -> dict[str, Any]:
    """Re-make the figures and ``report.md`` of an earlier run from its ``results.json``
    (e.g. after a change of plot style); the figures keep that run's date and labels."""
    path = out / RESULTS_JSON
    if not path.is_file():
        raise InvalidInputError(f"no {RESULTS_JSON} in {out} to redraw from")
    results: dict[str, Any] = json.loads(path.read_text(encoding="utf-8"))
    for name in results["experiments"]:
        results["figures"][name] = draw(results, name, out)
    write_atomic(out / REPORT_MD, render(results))
    return results


def write_atomic(path: Path, text: str) -> None:
    """Write ``text`` to ``path`` via a temporary file, fsync and rename."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            fh.write(text)
            fh.flush()
            os.fsync(fh.fileno())
        os.chmod(tmp, 0o644)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def run_paper(
    ds: Dataset,
    out: Path,
    cfg: BenchConfig,
    argv: list[str] | None = None,
    progress: Callable[[str], None] | None = None,
) -> dict[str, Any]:
    """Run ``cfg.experiments`` on ``ds``; write ``results.json``, ``report.md`` and PNGs."""
    report = progress or (lambda msg: None)
    out.mkdir(parents=True, exist_ok=True)
    started = time.perf_counter()
    ctx = run_context(argv)
    if cfg.uses_torch():
        ctx["machine"]["torch_threads"] = set_torch_threads(cfg.torch_threads)
    results: dict[str, Any] = {
        "dataset": ds.describe(), "context": ctx, "config": cfg.to_dict(),
        "experiments": {}, "figures": {}, "experiment_seconds": {},
    }  # fmt: skip
    runners: dict[str, Callable[[], dict[str, Any]]] = {
        "storage": lambda: run_storage(ds, cfg, report),
        "timing": lambda: run_timing(ds, cfg, report),
        "patterns": lambda: run_patterns(ds, cfg, report),
        "chunking": lambda: run_chunking(cfg, report),
        "retrieval": lambda: run_retrieval(ds, cfg, report),
    }
    for name in cfg.experiments:
        t0 = time.perf_counter()
        res = runners[name]()
        results["experiments"][name] = res
        results["experiment_seconds"][name] = time.perf_counter() - t0
        results["figures"][name] = draw(results, name, out)
        results["elapsed_seconds"] = time.perf_counter() - started
        write_atomic(out / RESULTS_JSON, json.dumps(results, indent=1))  # partial results survive
    results["elapsed_seconds"] = time.perf_counter() - started
    write_atomic(out / RESULTS_JSON, json.dumps(results, indent=1))
    write_atomic(out / REPORT_MD, render(results))
    return results

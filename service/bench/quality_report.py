"""Tables of ``gridplace bench quality``; its figure is :mod:`service.bench.frontier_figure`."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from rich.console import Console
from rich.table import Table

from service.bench.frontier_figure import plot_frontier

__all__ = ["markdown_tables", "plot_frontier", "print_report"]
DRIVE_ORDER = ("A", "B", "all")


def _cell(p: dict[str, float]) -> str:
    return "/".join(f"{100 * p[t]:.1f}" for t in p)


def adapted_cell(result: dict[str, Any], drive: str, kind: str, tol: str) -> str:
    """Adapted precision (%) of ``kind`` on ``drive`` at ``tol``; "—" where the result has none
    (a report from before adaptation, merged)."""
    figures = result["drives"].get(drive, {}).get(f"{kind}_adapted")
    return "—" if figures is None else f"{100 * figures[tol]:.1f}"


def _bytes(n: float) -> str:
    for unit, size in (("MB", 1e6), ("kB", 1e3)):
        if n >= size:
            return f"{n / size:.1f} {unit}"
    return f"{n:.0f} B"


def protocol_table(dataset: dict[str, Any], block: dict[str, Any], tolerances: list[int],
                   kind: str, headline: int = 5) -> Table:  # fmt: skip
    """One row per method: precision per drive (``kind``: single or sequence), each beside
    its adapted figure at ``headline``; the single frame table also gives the storage."""
    tol = "/".join(f"±{t}" for t in tolerances)
    title = f"{dataset['name']} (N={dataset['N']}, d={dataset['d']}) {block['label']}: {kind}"
    t = Table(title=f"{title}, precision % at {tol}", title_justify="left")
    drives = [d for d in DRIVE_ORDER if any(d in r["drives"] for r in block["results"])]
    t.add_column("method")
    if kind == "single":
        t.add_column("actual (paper) bytes")
        t.add_column("vs NN", justify="right")
    for d in drives:
        t.add_column(d, justify="right")
        t.add_column(f"{d} adapted ±{headline}", justify="right")
    for r in block["results"]:
        cells = [r["method"]]
        if kind == "single":
            ratio = r.get("bytes_vs_exact_nn")
            cells += [f"{_bytes(r['actual_bytes'])} ({_bytes(r['paper_bytes'])})",
                      f"{100 * ratio:.1f}%" if ratio is not None else "–"]  # fmt: skip
        for d in drives:
            cells += [_cell(r["drives"][d][kind]) if d in r["drives"] else "–",
                      adapted_cell(r, d, kind, str(headline))]  # fmt: skip
        t.add_row(*cells)
    if kind == "single":
        for e in block["errors"]:
            t.add_row(e["method"], f"[red]failed: {e['error']}[/red]", "",
                      *[""] * (2 * len(drives)))  # fmt: skip
    return t


def print_report(report: dict[str, Any], console: Console) -> None:
    for entry in report["sets"]:
        console.print(f"[bold]{entry['dataset']['label']}[/bold]")
        for block in entry["protocols"].values():
            for kind in ("single", "sequence"):
                console.print(protocol_table(entry["dataset"], block, report["tolerances"], kind,
                                             report["headline_tolerance"]))  # fmt: skip
    console.print(
        "A = first half of the query drive (validation), B = second half (test), all = both; "
        "protocol (b) folds test only on the half they did not train on. "
        f"Sequence filter: {report['tuned_where']['sequence_filter']}. {adaptation_note(report)}"
    )


def adaptation_note(report: dict[str, Any]) -> str:
    """One sentence on what the adapted columns are ("—": measured before adaptation)."""
    info = report.get("adaptation")
    if info is None:
        return "No adapted figures in this report."
    return (
        f"Adapted: {info['drives']}, {_config_text(info['config'])}, from each method's "
        "route statistics, or its training rows' where it keeps none; — = not measured."
    )


def _config_text(config: dict[str, Any]) -> str:
    """``alpha = 0.02, novelty = 1.0`` (every adaptation parameter the report recorded)."""
    return ", ".join(f"{k} = {v}" for k, v in config.items())


def headline_drive(block: dict[str, Any]) -> str:
    """The drive a figure shows: B (never tuned on) for protocol (a), the pooled unseen
    halves for (b)."""
    return "B" if block["protocol"] == "cross" else "all"


def _pct(p: float) -> str:
    return f"{100 * p:.1f}"


def markdown_tables(report: dict[str, Any]) -> str:
    """Markdown tables of a report: per descriptor set × protocol, one row per method with
    its bytes and precision at every tolerance, single frame and sequence, per drive."""
    tols = [str(t) for t in report["tolerances"]]
    lines: list[str] = [
        (
            "Drives: A = first half of the query traversal (validation), B = second half "
            "(test), all = both. In (b) A and B are each fold's unseen half (the fold trained "
            "on the reference plus the other half) and all pools them. "
            f"Sequence filter: {report['tuned_where']['sequence_filter']}. "
            f"{adaptation_note(report)}"
        ),
        "",
    ]
    head_tol = str(report["headline_tolerance"])
    for entry in report["sets"]:
        ds = entry["dataset"]
        for block in entry["protocols"].values():
            drives = [d for d in DRIVE_ORDER if any(d in r["drives"] for r in block["results"])]
            lines += [(f"**{ds['name']}** (N = {ds['N']}, d = {ds['d']}), {block['label']}. "
                       f"Precision % at ±{'/±'.join(tols)} frames."), ""]  # fmt: skip
            head = ["method", "actual bytes (paper)", "vs exact NN"]
            for kind in ("single", "sequence"):
                head += [c for d in drives for c in (f"{kind} {d}", f"adapted ±{head_tol}")]
            lines += ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
            for r in block["results"]:
                ratio = r.get("bytes_vs_exact_nn")
                size = f"{_bytes(r['actual_bytes'])} ({_bytes(r['paper_bytes'])})"
                cells = [f"`{r['method']}`", size,
                         f"{100 * ratio:.1f} %" if ratio is not None else "–"]  # fmt: skip
                for kind in ("single", "sequence"):
                    for d in drives:
                        cells += ["/".join(_pct(r["drives"][d][kind][t]) for t in tols)
                                  if d in r["drives"] else "–",
                                  adapted_cell(r, d, kind, head_tol)]  # fmt: skip
                lines.append("| " + " | ".join(cells) + " |")
            for e in block["errors"]:
                lines.append(f"| `{e['method']}` | failed: {e['error']} |" + " |" * (len(head) - 2))
            lines.append("")
    return "\n".join(lines)

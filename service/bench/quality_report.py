"""Tables and the precision-vs-bytes frontier figure of ``gridplace bench quality``."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from rich.console import Console
from rich.table import Table

from service.harness.quality_methods import FAMILY_LABELS

DRIVE_ORDER = ("A", "B", "all")
COLORS = {"exact_nn": "tab:green", "exact_nn_projected": "tab:olive", "pq": "tab:red",
          "yu": "tab:orange", "gridplace": "tab:blue"}  # fmt: skip


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


def pareto(points: list[tuple[float, float, str]]) -> list[tuple[float, float, str]]:
    """The points (bytes, precision, name), sorted by bytes, that no smaller point beats."""
    front: list[tuple[float, float, str]] = []
    for p in sorted(points):
        if not front or p[1] > front[-1][1]:
            front.append(p)
    return front


def _adapted_points(ax: Any, rows: list[dict[str, Any]], drive: str, kind: str, tol: str) -> None:
    """Each method's adapted figure as an open triangle of its family's colour, joined to its
    unadapted point by a dotted line (methods measured before adaptation have none)."""
    labelled = False
    for r in rows:
        figures = r["drives"][drive].get(f"{kind}_adapted")
        if figures is None:
            continue
        x, before = r["actual_bytes"], 100 * r["drives"][drive][kind][tol]
        after = 100 * figures[tol]
        color = COLORS.get(r["family"], "k")
        ax.plot([x, x], [before, after], ":", color=color, lw=0.8)
        ax.plot([x], [after], "^", mfc="none", color=color, ms=6,
                label=None if labelled else "adapted (open ▲)")  # fmt: skip
        labelled = True


def _panel(ax: Any, entry: dict[str, Any], block: dict[str, Any], kind: str, tol: str) -> None:
    from matplotlib.ticker import NullFormatter

    drive = headline_drive(block)
    rows = [r for r in block["results"] if drive in r["drives"]]
    for fam in dict.fromkeys(r["family"] for r in rows):
        pts = sorted((r["actual_bytes"], 100 * r["drives"][drive][kind][tol], r["method"])
                     for r in rows if r["family"] == fam)  # fmt: skip
        color = COLORS.get(fam, "k")
        ax.plot([p[0] for p in pts], [p[1] for p in pts], "o", color=color, ms=5,
                label=FAMILY_LABELS.get(fam, fam))  # fmt: skip
        front = pareto(pts)
        if len(front) > 1:
            ax.plot([p[0] for p in front], [p[1] for p in front], "-", color=color, lw=0.8)
        for x, y, name in pts:
            ax.annotate(name, (x, y), fontsize=6, xytext=(3, 2), textcoords="offset points")
    _adapted_points(ax, rows, drive, kind, tol)
    ds = entry["dataset"]
    ax.set_xscale("log")
    ax.xaxis.set_minor_formatter(NullFormatter())
    ax.set_ylim(bottom=0)
    ax.set_xlabel("actual bytes stored")
    ax.set_ylabel(f"precision ±{tol} (%), drive {drive}")
    ax.set_title(f"{ds['name']} · {block['protocol']} · {kind}", fontsize=9)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, loc="best")


def plot_frontier(report: dict[str, Any], path: Path) -> Path:
    """Precision at the headline tolerance against actual bytes, one panel per descriptor
    set × protocol × (single, sequence); every setting a labelled point, each family's
    precision-vs-bytes frontier a line, and each setting's adapted figure an open triangle."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    panels = [(e, b, kind) for e in report["sets"] for b in e["protocols"].values()
              for kind in ("single", "sequence")]  # fmt: skip
    cols = 2
    rows = max(1, (len(panels) + cols - 1) // cols)
    fig, axes = plt.subplots(rows, cols, figsize=(6.4 * cols, 4.2 * rows), squeeze=False)
    tol = str(report["headline_tolerance"])
    for ax, (entry, block, kind) in zip(axes.ravel(), panels, strict=False):
        _panel(ax, entry, block, kind, tol)
    for ax in axes.ravel()[len(panels) :]:
        ax.axis("off")
    ctx = report["context"]
    foot = f"{ctx['date']} · {ctx['machine']['cores']} cores · gridplace {ctx['git_commit']}"
    config = (report.get("adaptation") or {}).get("config")
    adapted = f" · adapted: {_config_text(config)}" if config else ""
    fig.text(0.01, 0.005, f"{foot} · filter: HMM defaults{adapted}", fontsize=7, color="0.35")
    fig.tight_layout(rect=(0, 0.02, 1, 1))
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=80)
    plt.close(fig)
    return path


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

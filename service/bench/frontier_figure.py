"""The one figure of ``gridplace bench quality``: precision against bytes stored per frame, for
the main methods, single frame and as a drive, on the test half of the route.

One descriptor set (the default CNN's when the report has it), protocol (a) — summer map,
winter drive — drive B (never tuned on). Left: single frames as sent (what ``/v1/localize``
answers a query without a vehicle); right: the drive through the sequence filter, adapted as
the service adapts drives. Bytes per frame on a log scale: a method whose storage does not
grow with the route would move left as the route grows; every method here stores in
proportion to N except the sub-linear codes (``paper``, ``ridge``, Yu et al.). Every other
setting and both descriptor sets are in the report's tables.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

# method → label in the figure (the methods shown, in drawing order)
SHOWN = {
    "exact-nn": "exact NN (float32 rows)",
    "pq-m64": "PQ, m = 64",
    "nn-pca256": "exact NN in robust's PCA-256 space",
    "robust": "robust (default): int8 prototype per frame",
    "residue": "residue: k = 2 digits i mod τ",
    "paper": "paper: LIBLINEAR, mixed radix",
    "ridge": "ridge: paper's code, ridge",
    "yu": "Yu et al. (co-prime code)",
}
COLORS = {"exact_nn": "tab:green", "exact_nn_projected": "tab:olive", "pq": "tab:red",
          "yu": "tab:orange", "gridplace": "tab:blue"}  # fmt: skip
_OFFSETS = ((7, 3), (7, -11), (-7, 3), (-7, -11), (7, 13), (-7, 13), (7, -22), (-7, -22),
            (0, 16), (0, -24), (7, 24), (-7, 24), (12, -36), (-12, -36), (12, -50), (-12, -50),
            (20, -64), (-20, -64), (20, -78), (-20, -78))


def _set(report: dict[str, Any]) -> dict[str, Any]:
    sets = report["sets"]
    return next((s for s in sets if s["dataset"]["name"].startswith("lite0")), sets[0])


def _points(block: dict[str, Any], tol: str) -> list[dict[str, Any]]:
    out = []
    for r in block["results"]:
        if r["method"] not in SHOWN or "B" not in r["drives"]:
            continue
        drive = r["drives"]["B"]
        seq = drive.get("sequence_adapted") or drive["sequence"]
        out.append({"method": r["method"], "family": r["family"],
                    "x": r["actual_bytes"] / r["n_places"], "single": 100 * drive["single"][tol],
                    "drive": 100 * seq[tol], "adapted": "sequence_adapted" in drive})  # fmt: skip
    order = list(SHOWN)
    return sorted(out, key=lambda p: order.index(p["method"]))


def _label(ax: Any, fig: Any, text: str, x: float, y: float, placed: list[Any]) -> None:
    """Annotate ``(x, y)`` at the first offset whose text stays inside the axes and overlaps
    neither a label placed before nor a point (``placed`` holds their boxes)."""
    renderer = fig.canvas.get_renderer()
    inside = ax.get_window_extent(renderer)
    for dx, dy in _OFFSETS:
        ha = "left" if dx > 0 else "right" if dx < 0 else "center"
        note = ax.annotate(text, (x, y), xytext=(dx, dy), textcoords="offset points",
                           fontsize=7.5, ha=ha)  # fmt: skip
        box = note.get_window_extent(renderer)  # the text alone (no leader line yet)
        clear = not any(box.overlaps(other) for other in placed)
        if clear and inside.x0 <= box.x0 and box.x1 <= inside.x1 and inside.y0 <= box.y0 \
                and box.y1 <= inside.y1:
            placed.append(box)
            if abs(dy) > 18:  # away from its point: a leader line to it
                note.remove()
                ax.annotate(text, (x, y), xytext=(dx, dy), textcoords="offset points",
                            fontsize=7.5, ha=ha,
                            arrowprops={"arrowstyle": "-", "color": "0.6", "lw": 0.6})  # fmt: skip
            return
        note.remove()
    placed.append(ax.annotate(text, (x, y), xytext=_OFFSETS[0], textcoords="offset points",
                              fontsize=7.5).get_window_extent(renderer))  # fmt: skip


def _point_boxes(ax: Any, fig: Any, points: list[dict[str, Any]], key: str) -> list[Any]:
    from matplotlib.transforms import Bbox

    fig.canvas.draw()
    out = []
    for p in points:
        cx, cy = ax.transData.transform((p["x"], p[key]))
        out.append(Bbox.from_extents(cx - 5, cy - 5, cx + 5, cy + 5))
    return out


def plot_frontier(report: dict[str, Any], path: Path) -> Path:
    """Write the figure to ``path`` (PNG)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import FuncFormatter

    entry = _set(report)
    block = entry["protocols"].get("cross") or next(iter(entry["protocols"].values()))
    tol = str(report["headline_tolerance"])
    points = _points(block, tol)
    fig, axes = plt.subplots(1, 2, figsize=(12.5, 5.0), sharex=True)
    panels = (("single", f"single frame, as sent: within ±{tol} frames (%)"),
              ("drive", f"as a drive (sequence filter, adapted): within ±{tol} frames (%)"))  # fmt: skip
    for ax, (key, ylabel) in zip(axes, panels, strict=True):
        for p in points:
            ax.plot([p["x"]], [p[key]], "o", ms=7, color=COLORS.get(p["family"], "k"),
                    mec="black" if p["method"] == "robust" else "none")  # fmt: skip
        ax.set_xscale("log")
        top = max(p[key] for p in points)
        ax.set_ylim(0, 105 if top > 80 else min(100, 10 * (top // 10 + 2)))
        ax.set_xlim(min(p["x"] for p in points) / 4, max(p["x"] for p in points) * 4)
        ax.xaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:,.0f} B"))
        ax.set_xlabel("bytes stored per frame (log scale)")
        ax.set_ylabel(ylabel)
        ax.grid(alpha=0.3, which="both")
    ds = entry["dataset"]
    fig.suptitle(f"Nordland summer map → winter drive, test half B: {ds['name']} descriptors "
                 f"(d = {ds['d']:,}, N = {ds['N']:,} frames)", fontsize=10)  # fmt: skip
    ctx = report["context"]
    fig.text(0.01, 0.01, f"{ctx['date']} · gridplace {ctx['git_commit']} · every setting and "
             "descriptor set: docs/results/quality/tables.md", fontsize=7, color="0.35")  # fmt: skip
    fig.tight_layout(rect=(0, 0.03, 1, 0.95))  # before the labels: it moves the axes
    for ax, (key, _) in zip(axes, panels, strict=True):
        placed = _point_boxes(ax, fig, points, key)
        for p in points:
            _label(ax, fig, SHOWN[p["method"]], p["x"], p[key], placed)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path

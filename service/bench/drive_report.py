"""Tables (rich and Markdown) and the figure of ``gridplace bench drive``."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from rich.console import Console
from rich.table import Table

SHORT_AT = (10, 50)  # precision of short drives after this many frames, in the tables
FIXED_PARTS = ("projection", "normalization", "masks")  # parts that do not grow with the route
COLUMNS = ("method", "map bytes", "code bytes", "single", "whole", "L90", "short@10", "short@50",
           "speed+stops (95 % interval)", "traffic (95 % interval)", "kidnap: median (p90), never",
           "reverse (reverse filter)")  # fmt: skip


def _bytes(n: float) -> str:
    for unit, size in (("MB", 1e6), ("kB", 1e3)):
        if n >= size:
            return f"{n / size:.2f} {unit}"
    return f"{n:.0f} B"


def code_bytes(method: dict[str, Any]) -> int:
    """A method's bytes beyond its fixed parts (projection, column statistics, masks): the
    part that grows with the route."""
    return int(method["bytes"] - sum(v for k, v in method["components"].items()
                                     if k in FIXED_PARTS))  # fmt: skip


def _pct(p: float | None) -> str:
    return "–" if p is None else f"{100 * p:.1f}"


def _pct_ci(m: dict[str, Any]) -> str:
    """A protocol's precision with its 95 % interval over the drives, where it has one."""
    ci = m.get("interval95")
    return f"{_pct(m['precision'])} ({_pct(ci[0])}–{_pct(ci[1])})" if ci else _pct(m["precision"])


def _l90(short: dict[str, Any] | None) -> str:
    if short is None:
        return "–"
    return f"> {len(short['curve'])}" if short["l90"] is None else str(short["l90"])


def _kidnap(k: dict[str, Any] | None) -> str:
    if k is None:
        return "–"
    r = k["recovery"]
    if r["median"] is None:
        return f"never ({_pct(r['never'])} %)"
    return f"{r['median']:.0f} ({r['p90']:.0f}), {_pct(r['never'])} %"


def _odometry_cells(results: dict[str, Any]) -> list[tuple[str, str]]:
    """(column, cell) of speed+stops with each odometry level."""
    levels = {k: v for k, v in results.items() if k != "none"}
    if levels and all(v.get("available") is False for v in levels.values()):
        return [("speed+stops with odometry", "n/a")]
    return [(f"speed+stops, odometry {k.removeprefix('odometry_')}",
             _pct(v["speed"]["precision"]) if "speed" in v else "–")
            for k, v in levels.items()]  # fmt: skip


def rows(report: dict[str, Any], config: str, split: str) -> list[tuple[list[str], list[str]]]:
    """(header, cells) per method for one filter configuration and split."""
    out = []
    for name, m in report["methods"].items():
        res = m["results"].get(config, {}).get(split)
        if res is None:
            continue
        f = res["none"]
        short = f.get("short")
        curve = short["curve"] if short else []
        rev = f.get("reverse")
        periods = m.get("periods") or []
        label = f"{name} ({'×'.join(map(str, periods))})" if len(periods) > 1 else name
        cells = [
            label, _bytes(m["bytes"]), _bytes(code_bytes(m)), _pct(m["single"][split]),
            _pct(f["whole"]["precision"]) if "whole" in f else "–", _l90(short),
            *(_pct(curve[at - 1]) if len(curve) >= at else "–" for at in SHORT_AT),
            _pct_ci(f["speed"]) if "speed" in f else "–",
            _pct_ci(f["traffic"]) if "traffic" in f else "–", _kidnap(f.get("kidnap")),
            f"{_pct(rev['precision'])} ({_pct(rev['precision_reverse_filter'])})" if rev else "–",
        ]  # fmt: skip
        odo = _odometry_cells(res)
        out.append(([*COLUMNS, *(c for c, _ in odo)], [*cells, *(v for _, v in odo)]))
    return out


def filter_setting(f: dict[str, Any]) -> str:
    """The filter parameters a reader compares runs by, from a run's ``filter`` record."""
    parts = [f"speeds {f['min_speed']:g}–{f['max_speed']:g} by {f['speed_step']:g}",
             "reverse" if f.get("reverse") else "forwards only",
             f"stops {f['stop_probability']:g}" if f.get("stop_probability") else "no stopped state",
             f"relocalisation {f['relocalization']:g}", f"emission scale {f['emission_scale']:g}"]  # fmt: skip
    if f.get("repeat_novelty"):
        reading = "repeats tempered and speed evidence" if f.get("repeat_speed") else "repeats tempered"
        parts.append(f"{reading} (novelty {f['repeat_novelty']:g})")
    return ", ".join(parts)


def _title(report: dict[str, Any], config: str, split: str) -> str:
    lo, hi = report["splits"][split]
    if config == "default":
        what = "filter defaults of this run" + (f" ({filter_setting(report['filter'])})" if "filter" in report else "")
    else:
        what = f"filter tuned on A ({report['tuning']['mode']})"
    return (f"{report['data']['label']} — drives in {split} [{lo}, {hi}), {what}, "
            f"precision % within ±{report['tolerance']} frames")  # fmt: skip


def notes(report: dict[str, Any]) -> str:
    ad = report["adaptation"]
    odo = report["odometry"]
    return (
        f"Adaptation: {'on, ' + ad['order'] if ad['applied'] else 'off'}. Code bytes: the map's "
        f"bytes beyond its fixed parts ({', '.join(FIXED_PARTS)}). "
        f"L90: first L with ≥ {100 * report['l90_target']:.0f} % of {report['settings']['short_drives']} "
        f"short drives within ±{report['tolerance']} after L frames. Kidnap: frames after the jump "
        f"until within ±{report['tolerance']} for {report['recovery_hold']} frames, median (p90) of "
        "recovered drives, share never recovered. Speed: 0.5–2 reference frames per query frame "
        "(piecewise-constant, smooth and accelerating profiles), stops of 5–20 repeated frames. "
        "Traffic: cruising at 0.3–3 with ramps, braking into and accelerating out of stops of "
        f"20–60 near-identical frames (descriptor noise {report['settings'].get('stop_noise', 0)}). "
        + (f"Odometry: {odo['model']}." if odo["available"] else
           "Odometry: n/a — this build's filter takes no odometry (not measured).")
    )  # fmt: skip


def print_report(report: dict[str, Any], console: Console) -> None:
    for config in ("default", "tuned"):
        for split in report["reported_splits"]:
            body = rows(report, config, split)
            if not body:
                continue
            t = Table(title=_title(report, config, split), title_justify="left")
            for c in body[0][0]:
                t.add_column(c, justify="left" if c == "method" else "right")
            for _, cells in body:
                t.add_row(*cells)
            console.print(t)
    if report.get("tuning"):
        for name, cfg in report["tuning"]["chosen"].items():
            picked = {k: cfg[k] for k in report["tuning"]["grid"]}
            console.print(f"tuned on A for {name}: {picked}")
    console.print(notes(report))


def markdown(report: dict[str, Any]) -> str:
    lines: list[str] = []
    for config in ("default", "tuned"):
        for split in report["reported_splits"]:
            body = rows(report, config, split)
            if not body:
                continue
            head = body[0][0]
            lines += [f"**{_title(report, config, split)}**", "",
                      "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]  # fmt: skip
            lines += ["| " + " | ".join([f"`{c[0]}`", *c[1:]]) + " |" for _, c in body]
            lines.append("")
    if report.get("tuning"):
        for name, cfg in report["tuning"]["chosen"].items():
            picked = ", ".join(f"{k} = {cfg[k]}" for k in report["tuning"]["grid"])
            lines.append(f"- tuned on A for `{name}`: {picked}")
        lines.append("")
    lines.append(notes(report))
    return "\n".join(lines) + "\n"


def plot(report: dict[str, Any], path: Path, split: str = "B") -> Path | None:
    """Drive precision (whole, speed+stops) and L90 against map bytes (log x); ``None`` when
    matplotlib is not installed."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return None
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(11, 4.2))
    drawn = {ax1: False, ax2: False}
    for name, m in report["methods"].items():
        f = m["results"]["default"][split]["none"]
        x = m["bytes"]
        for key, marker in (("whole", "o"), ("speed", "s")):
            if key in f:
                ax1.scatter(x, 100 * f[key]["precision"], marker=marker,
                            color="C0" if key == "whole" else "C1")  # fmt: skip
                drawn[ax1] = True
        if "whole" in f or "speed" in f:
            y = f["whole"]["precision"] if "whole" in f else f["speed"]["precision"]
            ax1.annotate(name, (x, 100 * y), fontsize=7, xytext=(3, 3), textcoords="offset points")
        if "short" in f:
            drawn[ax2] = True
            s = f["short"]
            lmax = len(s["curve"])
            y = s["l90"] if s["l90"] is not None else lmax * 1.05
            ax2.scatter(x, y, marker="o" if s["l90"] is not None else "^", color="C2")
            ax2.annotate(name, (x, y), fontsize=7, xytext=(3, 3), textcoords="offset points")
    ax1.scatter([], [], marker="o", color="C0", label="whole drive")
    ax1.scatter([], [], marker="s", color="C1", label="variable speed + stops")
    ax1.set(xlabel="map bytes", ylabel=f"precision % (±{report['tolerance']})",
            title=f"drives in {split}, filter defaults, no odometry")  # fmt: skip
    ax1.legend(fontsize=8)
    ax2.set(xlabel="map bytes", ylabel="L90 (frames; ▲ = not reached)",
            title="frames to 90 % from a fresh start")  # fmt: skip
    for ax, missing in ((ax1, "no whole or variable-speed drives"), (ax2, "no short drives")):
        if drawn[ax]:
            ax.set_xscale("log")
        else:  # a run of other protocols: say so instead of an empty log axis
            ax.text(0.5, 0.5, f"{missing} in this run", ha="center", va="center",
                    transform=ax.transAxes)
    fig.suptitle(report["data"]["label"], fontsize=9)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path

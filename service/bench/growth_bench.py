"""Storage growth to a million frames, on the paper's terms and on ours.

A SYNTHETIC route (the generator of ``gridplace bench scale``) is written once at the largest
N; every smaller N is its first N frames. At each N, gridplace is trained with a small grid of
settings — fixed *chunk size* (storage grows linearly with the number of chunks) and a fixed
*number of chunks* (each chunk's periods grow like √(N/C)) at two ρ — and scored on noisy
queries of random frames (precision within ±``tolerance`` frames). Exact NN and product
quantisation (faiss) are measured where N ≤ ``baseline_frames`` and their storage is exact at
every N (codes and stored frames are linear in N; PQ's codebooks are constant). Per method the
storage is fitted both as ``c·N^a`` and in the paper's form ``MB = N^a``, for each fixed
setting and for the cheapest setting reaching ``target`` precision.
"""

from __future__ import annotations

import json
import math
import os
import platform
import tempfile
import time
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np
from rich.console import Console
from rich.table import Table

from service.bench.scale_bench import _in_child
from service.encoding.synthetic import SYNTHETIC_LABEL, route_queries, write_route
from service.harness.powerlaw import fit_paper_form, fit_power_law

console = Console()

SETTINGS: tuple[tuple[str, dict[str, Any]], ...] = (
    ("chunks of 10k frames, ρ=0.5", {"frames_per_chunk": 10_000, "rho": 0.5}),
    ("chunks of 10k frames, ρ=0.25", {"frames_per_chunk": 10_000, "rho": 0.25}),
    ("10 chunks, ρ=0.5", {"chunks": 10, "rho": 0.5}),
    ("10 chunks, ρ=0.25", {"chunks": 10, "rho": 0.25}),
)


def _queries(route: str, n: int, n_queries: int, noise: float) -> tuple[np.ndarray, np.ndarray]:
    X = np.load(route, mmap_mode="r")
    rows = np.sort(np.random.default_rng(n).choice(n, min(n_queries, n), replace=False))
    return rows, route_queries(X, rows, noise, seed=1)


def _gridplace_child(route: str, n: int, setting: dict[str, Any], trainer: str, n_queries: int,
                     noise: float, tolerance: int, out: Any) -> None:  # fmt: skip
    from service.encoding import ModelParams, build_model, precision_at

    X = np.load(route, mmap_mode="r")[:n]
    chunks = setting.get("chunks") or max(1, n // setting["frames_per_chunk"])
    params = {"trainer": trainer, "n_patterns": 2, "rho": setting["rho"], "n_chunks": chunks,
              "n_jobs": -1}  # fmt: skip
    start = time.perf_counter()
    model = build_model(ModelParams.parse(**params)).fit(X)
    seconds = time.perf_counter() - start
    rows, Q = _queries(route, n, n_queries, noise)
    fp = model.footprint()
    out.put({"train_seconds": seconds, "params": params, "paper_bytes": fp.paper_bytes,
             "actual_bytes": fp.actual_bytes,
             "precision": precision_at(model.predict(Q), rows, tolerance)})  # fmt: skip


def _baseline_child(route: str, n: int, method: str, n_queries: int, noise: float,
                    tolerance: int, out: Any) -> None:  # fmt: skip
    from service.encoding import ExactNN, PQIndex, precision_at

    X = np.asarray(np.load(route, mmap_mode="r")[:n])
    m = math.gcd(64, X.shape[1])  # sub-quantizers must divide d
    model = ExactNN() if method == "exact_nn" else PQIndex(n_subquantizers=m)
    model.fit(X)
    del X
    rows, Q = _queries(route, n, n_queries, noise)
    fp = model.footprint()
    out.put({"paper_bytes": fp.paper_bytes, "actual_bytes": fp.actual_bytes, "m": m,
             "precision": precision_at(model.predict(Q), rows, tolerance)})  # fmt: skip


def _fits(ns: list[int], paper: list[float], actual: list[float]) -> dict[str, Any] | None:
    if len(ns) < 2:
        return None
    return {"c_N_a_paper_bytes": fit_power_law(ns, paper).to_dict(),
            "c_N_a_actual_bytes": fit_power_law(ns, actual).to_dict(),
            "paper_form_MB": fit_paper_form(ns, paper).to_dict()}  # fmt: skip


def run_growth_bench(sizes: list[int], d: int, region_length: int, noise: float, n_queries: int,
                     tolerance: int, target: float, baseline_frames: int, trainer: str,
                     out: Path, figure: Path | None, work_dir: Path | None = None) -> dict[str, Any]:  # fmt: skip
    sizes = sorted(sizes)
    rows: list[dict[str, Any]] = []
    with tempfile.TemporaryDirectory(prefix="gridplace-growth-", dir=work_dir) as tmp:
        route = str(Path(tmp) / "route.npy")
        with console.status(f"writing the SYNTHETIC route ({sizes[-1]:,} frames)…"):
            write_route(route, sizes[-1], d, region_length=region_length, seed=0)
        for n in sizes:
            for name, setting in SETTINGS:
                with console.status(f"N={n:,}: gridplace {name}…"):
                    r = _in_child(_gridplace_child, route, n, setting, trainer, n_queries, noise,
                                  tolerance)  # fmt: skip
                rows.append({"method": "gridplace", "setting": name, "N": n, **r})
                console.print(f"N={n:,} gridplace {name}: precision {r['precision']:.3f}, "
                              f"{r['paper_bytes'] / 1e6:.2f} MB paper, {r['train_seconds']:.0f} s")  # fmt: skip
            for method in ("exact_nn", "pq"):
                if n > baseline_frames:
                    continue
                with console.status(f"N={n:,}: {method}…"):
                    r = _in_child(_baseline_child, route, n, method, n_queries, noise, tolerance)
                rows.append({"method": method, "setting": method, "N": n, **r})
    curves = _curves(rows, sizes, baseline_frames, target)
    report = {
        "benchmark": "growth",
        "date": datetime.now(UTC).isoformat(),
        "machine": {"cores": os.cpu_count(), "platform": platform.platform()},
        "data": f"{SYNTHETIC_LABEL}: write_route d={d}, region_length={region_length}, query "
                f"noise {noise}, {n_queries} queries of random frames per N, precision within "
                f"±{tolerance} frames",
        "target": target,
        "points": rows,
        "curves": curves,
        "notes": f"exact NN and PQ trained and scored for N ≤ {baseline_frames:,}; their "
                 "storage beyond is the measured bytes scaled (exact NN: per frame; PQ: codes "
                 "per frame plus constant codebooks); MB = 10^6 bytes",
    }  # fmt: skip
    out.write_text(json.dumps(report, indent=2))
    if figure is not None:
        plot_growth(report, figure)
    _print(report)
    console.print(f"wrote {out}" + (f" and {figure}" if figure else ""))
    return report


def _curves(rows: list[dict[str, Any]], sizes: list[int], baseline_frames: int,
            target: float) -> list[dict[str, Any]]:  # fmt: skip
    curves = []
    for name, _ in SETTINGS:
        pts = sorted((r for r in rows if r["setting"] == name), key=lambda r: r["N"])
        curves.append(_curve(f"gridplace, {name}", pts))
    best = []
    for n in sizes:
        ok = [r for r in rows if r["method"] == "gridplace" and r["N"] == n and r["precision"] >= target]
        if ok:
            best.append(min(ok, key=lambda r: r["paper_bytes"]))
    curves.append(_curve(f"gridplace, cheapest with precision ≥ {target:.2f}", best))
    for method, label in (("exact_nn", "exact NN"), ("pq", "PQ (8-bit codes)")):
        measured = sorted((r for r in rows if r["method"] == method), key=lambda r: r["N"])
        if not measured:
            continue
        last = measured[-1]
        pts = list(measured)
        for n in sizes:
            if n > last["N"]:
                pts.append(_scaled(method, last, n))
        curves.append(_curve(label, pts))
    return curves


def _scaled(method: str, last: dict[str, Any], n: int) -> dict[str, Any]:
    """Storage of a baseline at ``n`` frames from its measurement at ``last['N']``."""
    k = n / last["N"]
    if method == "exact_nn":
        paper, actual = last["paper_bytes"] * k, last["actual_bytes"] * k
    else:  # PQ: m bytes per frame of codes, the rest (codebooks, normaliser) constant
        codes = float(last["m"]) * last["N"]
        paper = last["paper_bytes"] + codes * (k - 1)
        actual = last["actual_bytes"] + codes * (k - 1)
    return {"N": n, "paper_bytes": paper, "actual_bytes": actual, "precision": None,
            "setting": last["setting"], "scaled": True}  # fmt: skip


def _curve(label: str, pts: list[dict[str, Any]]) -> dict[str, Any]:
    ns = [p["N"] for p in pts]
    return {"label": label, "N": ns, "paper_bytes": [p["paper_bytes"] for p in pts],
            "actual_bytes": [p["actual_bytes"] for p in pts],
            "precision": [p.get("precision") for p in pts],
            "settings": [p.get("params", p.get("setting")) for p in pts],
            "fits": _fits(ns, [p["paper_bytes"] for p in pts], [p["actual_bytes"] for p in pts])}  # fmt: skip


def plot_growth(report: dict[str, Any], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(12, 4.8))
    for c in report["curves"]:
        if not c["N"]:
            continue
        style = "--" if c["label"].startswith(("exact", "PQ")) else "-"
        ax1.plot(c["N"], np.asarray(c["paper_bytes"]) / 1e6, style, marker="o", label=c["label"])
        prec = [(n, p) for n, p in zip(c["N"], c["precision"], strict=True) if p is not None]
        if prec:
            ax2.plot(*zip(*prec, strict=True), style, marker="o", label=c["label"])
    ax1.set(xscale="log", yscale="log", xlabel="route length N (frames)",
            ylabel="storage, paper formula (MB)", title="Storage against N (SYNTHETIC)")  # fmt: skip
    ax2.set(xscale="log", xlabel="route length N (frames)", ylim=(0, 1.02),
            ylabel="precision (noisy queries)", title="Precision against N (SYNTHETIC)")  # fmt: skip
    ax2.axhline(report["target"], color="grey", lw=0.8, ls=":")
    ax1.legend(fontsize=7)
    ax1.grid(True, which="both", alpha=0.3)
    ax2.grid(True, alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _print(report: dict[str, Any]) -> None:
    t = Table(title="storage growth (SYNTHETIC) — both fits over every N of each curve")
    for col in ("curve", "N", "storage MB (paper) at largest N", "precision", "a of c·N^a",
                "a of MB = N^a"):  # fmt: skip
        t.add_column(col)
    for c in report["curves"]:
        if not c["N"]:
            t.add_row(c["label"], "never", "", "", "", "")
            continue
        f = c["fits"]
        prec = [p for p in c["precision"] if p is not None]
        t.add_row(c["label"], ", ".join(f"{n:,}" for n in c["N"]),
                  f"{c['paper_bytes'][-1] / 1e6:,.2f}",
                  " / ".join(f"{p:.2f}" for p in prec) or "—",
                  f"{f['c_N_a_paper_bytes']['a']:.2f}" if f else "—",
                  f"{f['paper_form_MB']['a']:.2f}" if f else "—")  # fmt: skip
    console.print(t)

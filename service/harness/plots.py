"""PNG figures (matplotlib, Agg backend); every figure carries a footer naming the dataset,
N, d, machine cores, date and commit, and a title with the parameters it used."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from service.harness.methods import METHOD_LABELS

DPI = 80
COLORS = {"gridplace": "tab:blue", "yu": "tab:orange", "exact_nn": "tab:green", "pq": "tab:red"}


def _finish(fig: Any, footer: str, path: Path) -> Path:
    fig.text(0.01, 0.005, footer, fontsize=7, color="0.35", ha="left", va="bottom")
    fig.tight_layout(rect=(0, 0.03, 1, 1))
    fig.savefig(path, dpi=DPI)
    plt.close(fig)
    return path


def plot_storage(res: dict[str, Any], meta: str, footer: str, path: Path) -> Path:
    targets = res["targets"]
    cols = min(2, len(targets))
    rows = int(np.ceil(len(targets) / cols))
    fig, axes = plt.subplots(rows, cols, figsize=(5.2 * cols, 3.8 * rows), squeeze=False)
    for ax, tgt in zip(axes.ravel(), targets, strict=False):
        for method, m in tgt["methods"].items():
            best = m["best"]
            if not best:
                continue
            ns = np.array([b["N"] for b in best])
            ys = np.array([b["paper_bytes"] for b in best])
            fit = m.get("fit_paper")
            lab = METHOD_LABELS.get(method, method)
            lab += f"  a={fit['a']:.2f}" if fit else "  (no fit)"
            ax.loglog(ns, ys, "o", color=COLORS.get(method), label=lab)
            if fit:
                xs = np.geomspace(ns.min(), ns.max(), 50)
                ax.loglog(xs, fit["c"] * xs ** fit["a"], "-", color=COLORS.get(method), lw=1)
        cond = "identical (train = test)" if tgt["condition"] == "identical" else "cross-condition"
        ax.set_title(f"{cond}: precision ≥ {tgt['target']:.0%} at ±{tgt['tolerance']}", fontsize=9)
        ax.set_xlabel("route length N (frames)")
        ax.set_ylabel("smallest storage (paper bytes)")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7)
    for ax in axes.ravel()[len(targets) :]:
        ax.axis("off")
    fig.suptitle(f"Storage to reach a target precision vs N — {meta}", fontsize=9)
    return _finish(fig, footer, path)


def plot_timing(res: dict[str, Any], meta: str, footer: str, path: Path) -> Path:
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(10.5, 3.9))
    keys = list(dict.fromkeys((r["method"], r["trainer"]) for r in res["rows"]))
    for method, trainer in keys:
        sel = [r for r in res["rows"] if (r["method"], r["trainer"]) == (method, trainer)]
        ns = [r["N"] for r in sel]
        style = "-o" if method == "gridplace" else "--s"
        lab = f"{'gridplace' if method == 'gridplace' else 'Yu'} / {trainer}"
        a1.loglog(ns, [r["train_seconds"] for r in sel], style, label=lab)
        a2.loglog(ns, [r["query_us_per_descriptor_batch"] for r in sel], style, label=lab)
    a1.set_ylabel("training time (s)")
    a2.set_ylabel("query time (µs / descriptor, batch)")
    for ax in (a1, a2):
        ax.set_xlabel("route length N (frames)")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7)
    fig.suptitle(f"Training and query time vs N — {meta}", fontsize=9)
    return _finish(fig, footer, path)


def plot_patterns(res: dict[str, Any], meta: str, footer: str, path: Path) -> Path:
    fig, ax = plt.subplots(figsize=(7.6, 4.2))
    tol = str(res["cross_tolerance"])
    for method in dict.fromkeys(r["method"] for r in res["rows"]):
        sel = [r for r in res["rows"] if r["method"] == method]
        ks = [r["k"] for r in sel]
        lab = METHOD_LABELS.get(method, method)
        ax.plot(ks, [r["identical"]["0"] for r in sel], "-o", color=COLORS.get(method),
                label=f"{lab}: identical ±0")  # fmt: skip
        ax.plot(ks, [r["cross"][tol] for r in sel], "--s", color=COLORS.get(method),
                label=f"{lab}: cross ±{tol}")  # fmt: skip
    ax.set_xticks(sorted({r["k"] for r in res["rows"]}))
    ax.set_xlabel("number of patterns k (τ ≈ N^(1/k))")
    ax.set_ylabel("precision")
    ax.set_ylim(0, 1.02)
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=7)
    ax.set_title(f"Precision vs k — {meta}", fontsize=9)
    return _finish(fig, footer, path)


def plot_chunking(res: dict[str, Any], meta: str, footer: str, path: Path) -> Path:
    fig, ax = plt.subplots(figsize=(7.6, 4.2))
    tols = res["tolerances"]
    xs = [max(t, 0.5) for t in tols]
    for i, (name, m) in enumerate(res["models"].items()):
        for cond, style in (("noisy", "-o"), ("identical", "--s")):
            ys = [m[cond]["precision"][str(t)] for t in tols]
            ax.semilogx(xs, ys, style, color=f"C{i}", label=f"{name}: {cond} queries")
    ax.set_xlabel("frame tolerance (0 plotted at 0.5)")
    ax.set_ylabel("precision")
    ax.set_ylim(0, 1.02)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_title(f"Chunking at scale (SYNTHETIC route) — {meta}", fontsize=9)
    return _finish(fig, footer, path)


def plot_retrieval(res: dict[str, Any], meta: str, footer: str, path: Path) -> Path:
    fig, axes = plt.subplots(1, 2, figsize=(10.5, 3.9))
    for ax, cond in zip(axes, ("identical", "cross"), strict=True):
        tol = None
        styles = {"gridplace": "-", "yu": "-.", "exact_nn": "--", "pq": ":"}
        for i, row in enumerate(res["rows"]):
            if "error" in row:
                continue
            pr = row[cond]["pr"]
            tol = row[cond]["pr_tolerance"]
            ax.plot(pr["recall"], pr["precision"], color=f"C{i}", ls=styles[row["method"]],
                    label=f"{row['label']} AP={pr['average_precision']:.2f}")  # fmt: skip
        ax.set_xlabel("recall (accepted and correct / all queries)")
        ax.set_ylabel("precision of accepted queries")
        ax.set_xlim(0, 1)
        ax.set_ylim(0, 1.02)
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=6)
        ax.set_title(f"{cond} queries, correct within ±{tol} frames", fontsize=9)
    fig.suptitle(f"Precision–recall by confidence rejection — {meta}", fontsize=9)
    return _finish(fig, footer, path)

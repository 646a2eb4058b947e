"""The figure of the default preset's scale benchmark: query time and stored bytes against N."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np



def _series(pts: list[dict[str, Any]]) -> dict[str, list[tuple[int, float, float]]]:
    """``name → [(N, single CPU s, stored bytes)]`` of every method measured at some N."""
    out: dict[str, list[tuple[int, float, float]]] = {}
    for p in pts:
        s, n = p["serve"], p["N"]
        preset = p["params"]["encoder_preset"]
        runs = [(preset, p["train"], s),
                *((name, o["train"], o["serve"]) for name, o in p.get("also", {}).items())]
        for name, train, sv in runs:
            for key in ("ivf", "flat"):
                if key in sv:
                    ivf = sv["inverted_file"]
                    probe = "" if key == "flat" or ivf is None else f", nprobe {ivf['nprobe']}"
                    out.setdefault(f"gridplace {name} ({key}{probe})", []).append(
                        (n, sv[key]["single"]["cpu_s"], train["artifact_bytes"]))
        for kind, f in p["faiss"].items():
            if "skipped" not in f:
                out.setdefault(f"FAISS {kind}", []).append(
                    (n, f["single"]["cpu_s"], f["index_bytes"]))
        e = p["exact_nn"]
        out.setdefault("exact NN (float32)", []).append(
            (n, e["single_s_at_N"], e["stored_bytes_at_N"]))
    return out


def plot_default_scale(report: dict[str, Any], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    pts = report["points"]
    fig, (ax_t, ax_b) = plt.subplots(1, 2, figsize=(11, 4.4))
    for name, rows in _series(pts).items():
        ns = [r[0] for r in rows]
        ax_t.plot(ns, np.asarray([r[1] for r in rows]) * 1e6, "-o", label=name)
        ax_b.plot(ns, np.asarray([r[2] for r in rows]) / 1e6, "-o", label=name)
    d = pts[0]["d"]
    ax_t.set(xscale="log", yscale="log", xlabel="route length N (frames)",
             ylabel="CPU time per single query (µs)", title=f"Query time (SYNTHETIC, d={d})")  # fmt: skip
    ax_b.set(xscale="log", yscale="log", xlabel="route length N (frames)",
             ylabel="stored MB", title="Bytes stored")  # fmt: skip
    for ax in (ax_t, ax_b):
        ax.grid(True, which="both", alpha=0.3)
    ax_t.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)

"""The default on short routes: its projection width chosen from the route
(:mod:`service.encoding.projection_width`: at most 0.7 N components and ``N·d`` bytes)
against the fixed PCA-256 it replaced and exact NN, on held-out slices of Nordland.

Slices of ``N`` consecutive places from the test half B (frames 1,788–3,575, never used for
a choice): each is a route of its own, trained on its summer frames and queried with their
winter frames, single frame within ±5 frames, as sent and adapted (the drive's running
statistics from the slice's own reference statistics, as the demo does). Descriptors: the
default CNN's (``/work/cache``-style ``.npy`` pairs given with ``--cnn``), the folder's raw
uint8 pixels and patch-normalised pixels.

    python -m service.bench.small_routes_bench --cnn REF.npy QRY.npy --out small.json
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import Any

import numpy as np

from service.bench.data import NORDLAND_SHAPE, shared_data_dir
from service.encoding import ExactNN, ModelParams, build_model
from service.encoding.adaptation import AppearanceAdapter
from service.encoding.base import precision_at
from service.encoding.features import patch_normalize
from service.harness.context import run_context

HALF_B = 1788  # the first frame of the test half
TOLERANCE = 5
SIZES = (100, 150, 200, 300, 450, 600)
SLICES_PER_SIZE = 3


def _slices(n_total: int, size: int) -> list[tuple[int, int]]:
    count = min(SLICES_PER_SIZE, (n_total - HALF_B) // size)
    return [(HALF_B + i * size, HALF_B + (i + 1) * size) for i in range(count)]


def _precision(model: Any, Q: np.ndarray) -> float:
    return float(precision_at(model.localize(Q).index, np.arange(Q.shape[0]), TOLERANCE))


def measure(name: str, ref: np.ndarray, qry: np.ndarray) -> list[dict[str, Any]]:
    """Every slice of every size of one descriptor set."""
    rows: list[dict[str, Any]] = []
    for size in SIZES:
        for start, stop in _slices(ref.shape[0], size):
            R = np.asarray(ref[start:stop], np.float64)
            Q = np.asarray(qry[start:stop], np.float64)
            adapted = AppearanceAdapter.for_reference(R).transform(Q)
            row: dict[str, Any] = {"descriptors": name, "n": size, "d": int(R.shape[1]),
                                   "start": start, "exact_nn_uint8_bytes": size * int(R.shape[1])}  # fmt: skip
            models = {"default": build_model(ModelParams()),
                      "pca256": build_model(ModelParams(auto_width=False)),
                      "exact_nn": ExactNN()}  # fmt: skip
            for key, model in models.items():
                model.fit(R)
                front = getattr(model, "normalizer_", None)
                row[key] = {
                    "bytes": int(model.footprint().actual_bytes),
                    "components": getattr(getattr(front, "projection", None), "n_components", None),
                    "single": _precision(model, Q),
                    "adapted": _precision(model, adapted),
                }
            rows.append(row)
    return rows


def summarise(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Means over the slices of each (descriptor set, N)."""
    out = []
    for key in sorted({(r["descriptors"], r["n"]) for r in rows}):
        group = [r for r in rows if (r["descriptors"], r["n"]) == key]
        entry: dict[str, Any] = {"descriptors": key[0], "n": key[1], "slices": len(group),
                                 "exact_nn_uint8_bytes": group[0]["exact_nn_uint8_bytes"]}  # fmt: skip
        for model in ("default", "pca256", "exact_nn"):
            entry[model] = {
                metric: float(np.mean([r[model][metric] for r in group]))
                for metric in ("bytes", "single", "adapted")
            }
            entry[model]["components"] = group[0][model]["components"]
        out.append(entry)
    return out


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cnn", nargs=2, type=Path, metavar=("REF", "QRY"),
                    help="CNN descriptors .npy of the reference and query traversals")
    ap.add_argument("--out", type=Path, required=True)
    args = ap.parse_args(argv)
    root = shared_data_dir()
    if root is None:
        raise SystemExit("no Nordland data in ../shared/data (or GRIDPLACE_SHARED_DATA)")
    base = root / "nordland-64x32"
    raw_ref = np.load(base / "reference.npy", allow_pickle=False)
    raw_qry = np.load(base / "query.npy", allow_pickle=False)
    sets: dict[str, tuple[np.ndarray, np.ndarray]] = {"raw-pixels": (raw_ref, raw_qry)}
    shape = (-1, *NORDLAND_SHAPE)
    sets["patchnorm"] = (patch_normalize(raw_ref.reshape(shape), 16),
                         patch_normalize(raw_qry.reshape(shape), 16))  # fmt: skip
    if args.cnn:
        sets["lite0-b4"] = (np.load(args.cnn[0], mmap_mode="r"), np.load(args.cnn[1], mmap_mode="r"))
    start = time.perf_counter()
    rows = [r for name, (ref, qry) in sets.items() for r in measure(name, ref, qry)]
    summary = summarise(rows)
    result = {"benchmark": "small routes: the default's projection width", "context": run_context(),
              "tolerance": TOLERANCE,
              "half": "B (frames 1788-3575)", "seconds": time.perf_counter() - start,
              "summary": summary, "slices": rows}  # fmt: skip
    args.out.write_text(json.dumps(result, indent=1))
    for s in summary:
        d, u, e = s["default"], s["pca256"], s["exact_nn"]
        print(f"{s['descriptors']:>10} N={s['n']:>4}: default {d['components']:>3} comp "
              f"{d['bytes'] / s['exact_nn_uint8_bytes']:6.1%} of uint8 NN, "
              f"P@5 {d['single']:.3f}/{d['adapted']:.3f} | fixed PCA-256 "
              f"{u['bytes'] / s['exact_nn_uint8_bytes']:6.1%}, {u['single']:.3f}/{u['adapted']:.3f}"
              f" | exact NN {e['single']:.3f}/{e['adapted']:.3f}")


if __name__ == "__main__":
    main()

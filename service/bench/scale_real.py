"""The inverted file of the default preset on real descriptors: precision against its flat scan.

One reference traversal trains the preset with an inverted file (``search="ivf"``); the other
traversal's frames (query ``i`` ↔ reference frame ``i``) are answered by the flat scan and
through the inverted file at its default ``nprobe`` and at larger shares of the lists:
precision within ±5 frames (over the whole route and over each half of it, so that a choice
made on the first half is reported on the second), agreement with the flat scan, the share of
the prototypes scored, and single-query CPU time (one BLAS thread). ``nlist`` trains the same
model with another number of lists (``None``: the default rule).
"""

from __future__ import annotations

import json
import time
from dataclasses import replace
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np
from rich.console import Console

from service.bench.scale_bench import _timed

console = Console()


def run_scale_real_bench(reference: Path, query: Path, out: Path, preset: str = "robust",
                         n_single: int = 200, label: str = "",
                         nlist: int | None = None) -> dict[str, Any]:  # fmt: skip
    from threadpoolctl import threadpool_limits

    from service.encoding import ModelParams, build_model, precision_at
    from service.encoding.ivf_scan import search
    from service.encoding.serving_plan import plan_for

    ref, qry = np.load(reference), np.load(query)
    truth = np.arange(qry.shape[0])
    halves = {"A": slice(0, len(truth) // 2), "B": slice(len(truth) // 2, len(truth))}

    def precision(index: np.ndarray) -> dict[str, float]:
        return {"route": precision_at(index, truth, 5),
                **{k: precision_at(index[h], truth[h], 5) for k, h in halves.items()}}  # fmt: skip

    start = time.perf_counter()
    model = build_model(ModelParams.parse(encoder_preset=preset, search="ivf"))
    model.nlist = nlist  # None: the default rule
    model.fit(ref)
    fit_s = time.perf_counter() - start
    plan = plan_for(model)
    ivf = plan.ivf
    assert ivf is not None
    dg = plan.phases[0].digits[0]
    Q = qry.astype(np.float64)
    Z = np.ascontiguousarray(plan.normalise(Q, np.float32).take(dg.columns, axis=1))
    rows: list[dict[str, Any]] = []
    with threadpool_limits(1):
        flat = model.localize(Q, search="flat").index
        p_flat = precision_at(flat, truth, 5)
        h_flat = precision(flat)
        singles = iter(range(10**9))
        flat_single = _timed(lambda: model.localize(Q[next(singles) % len(Q)][None, :],
                                                    search="flat"), n_single)  # fmt: skip
        fractions = (1 / 16, 1 / 8, 1 / 4, 1 / 2, 3 / 4)
        probes = sorted({ivf.nprobe, *(max(1, round(ivf.nlist * f)) for f in fractions),
                         ivf.nlist})  # fmt: skip
        for p in probes:  # every figure of one model: only the lists scanned differ
            index, _ = search(ivf, dg, Z, p)
            scanned = np.mean([ivf.candidates(lists).size for lists in ivf.lists(Z[:500], p)])
            plan.ivf = replace(ivf, nprobe=p)  # the whole localize, as the flat one is timed
            single = _timed(lambda: model.localize(Q[next(singles) % len(Q)][None, :]), n_single)
            h = precision(index)
            rows.append({"nprobe": p, "default": p == ivf.nprobe,
                         "share_scanned": float(scanned / model.n_frames_),
                         "precision_at_5": precision_at(index, truth, 5),
                         "points_below_flat": 100.0 * (p_flat - precision_at(index, truth, 5)),
                         "agrees_with_flat": float(np.mean(index == flat)),
                         "halves": {k: {"precision_at_5": v,
                                        "points_below_flat": 100.0 * (h_flat[k] - v)}
                                    for k, v in h.items() if k in halves},
                         "single": single})  # fmt: skip
            console.print(f"nprobe {p}/{ivf.nlist}: {rows[-1]['share_scanned']:.1%} scanned, "
                          f"P@5 {rows[-1]['precision_at_5']:.4f} (flat {p_flat:.4f}; "
                          f"B {h['B']:.4f}, flat {h_flat['B']:.4f}), "
                          f"{single['cpu_s'] * 1e6:,.0f} µs")  # fmt: skip
    report = {"benchmark": "scale-real", "date": datetime.now(UTC).isoformat(),
              "data": label or f"{reference} → {query}", "preset": preset,
              "N": int(model.n_frames_), "d": int(ref.shape[1]), "fit_seconds": fit_s,
              "nlist": ivf.nlist, "flat": {"precision_at_5": p_flat, "single": flat_single,
                       "halves": {k: {"precision_at_5": h_flat[k]} for k in halves}},
              "ivf": rows,
              "notes": "single: CPU time of one localize call (front-end included), one BLAS "
                       "thread; halves: A = the first half of the frames (queries to choose "
                       "on), B = the second (to report)"}  # fmt: skip
    out.write_text(json.dumps(report, indent=2))
    console.print(f"wrote {out}")
    return report

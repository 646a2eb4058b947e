"""Scale benchmark of the default preset: one SYNTHETIC route of up to a million frames,
served through the inverted file beside its own flat scan, exact NN and FAISS.

For every route length N the route is written to disk block by block (float32, memory-mapped),
and in one fresh child process each:

- **gridplace** (the preset, ``search="auto"``): trained and published to a registry (training
  time, peak RSS, artifact bytes), then loaded (load time, the memory loading added, settled and
  peak) and queried through the inverted file and through the flat scan of the same model
  (single and batch latency, precision within ±5 frames, agreement of the two), the inverted
  file at other ``nprobe`` for queries at each of ``sweep_noises``, and the sequence filter's
  per-frame cost (the frame scores every update needs, and the update);
- **FAISS IVF-SQ8** (``IndexIVFScalarQuantizer``, 8-bit codes, ≈ 4√N lists, the same share of
  lists probed) and **FAISS HNSW** (``IndexHNSWFlat``, M = 32; up to ``hnsw_max`` frames: its
  build takes too long beyond on two shared cores) on the same descriptors: build time, peak
  RSS, serialised bytes, load time and memory, latency, precision;
- the presets of ``also`` (the ``drive`` preset from ``gridplace bench scale``): trained and
  served as the default, beside it on the same route;
- **exact NN** on the descriptors (measured on the first ``exact_frames`` frames, scaled
  linearly in N: one product with every stored frame).

Query timings use one BLAS / OpenMP thread; each figure is a median, wall and CPU time.
"""

from __future__ import annotations

import json
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

from service.bench.scale_bench import (
    _exact_child,
    _in_child,
    _timed,
    _train_child,
    peak_rss_bytes,
    rss_bytes,
)
from service.encoding.synthetic import SYNTHETIC_LABEL, route_queries, write_route

console = Console()


def _queries(route: str, n_queries: int, noise: float) -> tuple[np.ndarray, np.ndarray]:
    X = np.load(route, mmap_mode="r")
    rows = np.sort(np.random.default_rng(7).choice(X.shape[0], n_queries, replace=False))
    return rows, route_queries(X, rows, noise, seed=1).astype(np.float64)


def _settle() -> tuple[int, int]:
    Path("/proc/self/clear_refs").write_text("5")  # peak RSS := current RSS (Linux)
    return rss_bytes(), peak_rss_bytes()


def _serve_child(route: str, registry: str, n_queries: int, n_single: int, batch: int,
                 noise: float, sweep_noises: list[float], out: Any) -> None:  # fmt: skip
    from threadpoolctl import threadpool_limits

    from service.encoding import precision_at
    from service.encoding.sequence import SequenceFilter
    from service.encoding.serving_plan import plan_for
    from service.registry import Registry

    rows, Q = _queries(route, n_queries, noise)
    base_rss, base_peak = _settle()
    start = time.perf_counter()
    model = Registry(Path(registry)).load_model("scale", 1)
    plan = plan_for(model)
    res: dict[str, Any] = {"load_seconds": time.perf_counter() - start,
                           "rss_after_load_bytes": rss_bytes() - base_rss,
                           "peak_during_load_bytes": max(0, peak_rss_bytes() - base_peak),
                           "inverted_file": None if plan.ivf is None else {
                               "nlist": plan.ivf.nlist, "nprobe": plan.ivf.nprobe,
                               "bytes": plan.ivf.nbytes}}  # fmt: skip
    n = model.n_frames_
    flat_batch = max(8, min(batch, int(2e8 // (n * 256))))  # the flat scan's batch: ≤ 200 MFMA
    with threadpool_limits(1):
        singles = iter(range(10**9))
        for search in ("ivf", "flat") if plan.ivf is not None else ("flat",):
            loc = (model.localize(Q, search=search) if search == "ivf" or plan.ivf is None
                   else _flat(model, Q))  # the reference scan of a frame-per-class model
            reps = n_single if search == "ivf" or n < 200_000 else max(5, n_single // 20)
            res[search] = {
                "precision_at_5": precision_at(loc.index, rows, 5),
                "precision_at_0": precision_at(loc.index, rows, 0),
                "single": _timed(lambda s=search: model.localize(  # type: ignore[misc]
                    Q[next(singles) % n_queries][None, :], search=s), reps),
                "batch_size": batch if search == "ivf" else flat_batch,
                "batch": {k: v / (batch if search == "ivf" else flat_batch) for k, v in _timed(
                    lambda s=search: model.localize(  # type: ignore[misc]
                        Q[: batch if s == "ivf" else flat_batch], search=s), 3).items()},
                "index": loc.index}  # fmt: skip
        if "ivf" in res:
            res["ivf_agrees_with_flat"] = float(np.mean(res["ivf"]["index"] == res["flat"]["index"]))
            res["nprobe_sweep"] = _sweep(model, plan, route, n_queries, sweep_noises, n_single,
                                         batch, Q)  # fmt: skip
        for key in ("ivf", "flat"):
            res.get(key, {}).pop("index", None)
        filt = SequenceFilter(n)
        L = model.frame_log_scores(Q[:1])[0]
        res["sequence"] = {
            "frame_scores": _timed(lambda: model.frame_log_scores(Q[next(singles) % n_queries][None, :]),
                                   2 if n >= 200_000 else 10),
            "filter_update": _timed(lambda: filt.update(L), 5 if n >= 200_000 else 20),
            "state_bytes": filt.nbytes}  # fmt: skip
    res["process_peak_rss_bytes"] = peak_rss_bytes()
    out.put(res)


def _sweep(model: Any, plan: Any, route: str, n_queries: int, noises: list[float],
           n_single: int, batch: int, Q: np.ndarray) -> dict[str, Any]:  # fmt: skip
    """Precision of the flat scan and of the inverted file at several ``nprobe`` (the default
    ×1/2 … ×4) for queries at each noise of ``noises``, and the latency at every ``nprobe``."""
    from dataclasses import replace

    from service.encoding import precision_at

    ivf = plan.ivf
    probes = sorted({min(ivf.nlist, max(1, int(ivf.nprobe * f))) for f in (1/2, 3/4, 1, 3/2, 2, 4)})
    out: dict[str, Any] = {"nlist": ivf.nlist, "default_nprobe": ivf.nprobe, "probes": probes,
                           "latency": {}, "noises": {}}  # fmt: skip
    singles = iter(range(10**9))
    try:
        for p in probes:
            plan.ivf = replace(ivf, nprobe=p)
            out["latency"][str(p)] = {
                "share_scanned": float(np.mean([ivf.candidates(lists).size for lists in
                                                ivf.lists(np.ascontiguousarray(
                                                    plan.normalise(Q[:200], np.float32)), p)])
                                       / model.n_frames_),
                "single": _timed(lambda: model.localize(Q[next(singles) % len(Q)][None, :]),
                                 max(5, n_single // 4)),
                "batch": {k: v / batch for k, v in
                          _timed(lambda: model.localize(Q[:batch]), 2).items()}}  # fmt: skip
        for noise in noises:
            rows, Qn = _queries(route, n_queries, noise)
            flat = _flat(model, Qn).index
            entry: dict[str, Any] = {"flat_precision_at_5": precision_at(flat, rows, 5)}
            for p in probes:
                plan.ivf = replace(ivf, nprobe=p)
                index = model.localize(Qn).index
                entry[str(p)] = {"precision_at_5": precision_at(index, rows, 5),
                                 "agrees_with_flat": float(np.mean(index == flat))}  # fmt: skip
            out["noises"][str(noise)] = entry
    finally:
        plan.ivf = ivf
    return out


def _flat(model: Any, Q: np.ndarray) -> Any:
    """The flat scan of every query of a model with one class per frame, 64 at a time however
    long the route (one pass over the weights per 64 queries instead of per 4 at 1M frames:
    the plan's block bound is for serving, this is the reference run of a benchmark). Not for
    a code with a label table, whose decode enumerates every frame per query."""
    from service.encoding import serving_plan

    saved = serving_plan._BLOCK_SCORES
    serving_plan._BLOCK_SCORES = max(saved, 64 * model.n_frames_)
    try:
        return model.localize(Q, search="flat")
    finally:
        serving_plan._BLOCK_SCORES = saved


def _faiss_child(route: str, kind: str, n_queries: int, n_single: int, batch: int,
                 noise: float, sweep_noises: list[float], work: str, out: Any) -> None:  # fmt: skip
    import faiss

    from service.encoding import precision_at
    from service.encoding.inverted_file import default_nlist, default_nprobe

    X = np.load(route, mmap_mode="r")
    n, d = X.shape
    start = time.perf_counter()
    if kind == "ivf_sq8":
        nlist = default_nlist(n)
        index = faiss.IndexIVFScalarQuantizer(faiss.IndexFlatL2(d), d, nlist,
                                              faiss.ScalarQuantizer.QT_8bit)  # fmt: skip
        take = np.sort(np.random.default_rng(0).choice(n, min(n, 48 * nlist), replace=False))
        index.train(np.ascontiguousarray(X[take]))
        index.nprobe = default_nprobe(nlist, n)
        extra: dict[str, Any] = {"nlist": nlist, "nprobe": int(index.nprobe)}
    else:
        index = faiss.IndexHNSWFlat(d, 32)
        index.hnsw.efConstruction = 40
        index.hnsw.efSearch = 64
        extra = {"M": 32, "efConstruction": 40, "efSearch": 64}
    for s in range(0, n, 65536):
        index.add(np.ascontiguousarray(X[s : s + 65536]))
    build = time.perf_counter() - start
    path = str(Path(work) / f"{kind}.faiss")
    faiss.write_index(index, path)
    build_peak = peak_rss_bytes()
    del index, X
    rows, Q = _queries(route, n_queries, noise)
    Q32 = np.ascontiguousarray(Q, dtype=np.float32)
    base_rss, base_peak = _settle()
    start = time.perf_counter()
    index = faiss.read_index(path)
    load = time.perf_counter() - start
    if kind == "ivf_sq8":
        index.nprobe = extra["nprobe"]
    else:
        index.hnsw.efSearch = 64
    res: dict[str, Any] = {"kind": kind, **extra, "build_seconds": build, "peak_rss_bytes": build_peak,
                           "index_bytes": os.path.getsize(path), "load_seconds": load,
                           "rss_after_load_bytes": rss_bytes() - base_rss,
                           "peak_during_load_bytes": max(0, peak_rss_bytes() - base_peak)}  # fmt: skip
    faiss.omp_set_num_threads(1)
    _, found = index.search(Q32, 1)
    res["precision_at_5"] = precision_at(found[:, 0], rows, 5)
    res["precision_at_0"] = precision_at(found[:, 0], rows, 0)
    res["precision_at_5_by_noise"] = {}
    for other in sweep_noises:
        rows_n, Qn = _queries(route, n_queries, other)
        _, found = index.search(np.ascontiguousarray(Qn, dtype=np.float32), 1)
        res["precision_at_5_by_noise"][str(other)] = precision_at(found[:, 0], rows_n, 5)
    singles = iter(range(10**9))
    res["single"] = _timed(lambda: index.search(Q32[next(singles) % n_queries][None, :], 1), n_single)
    res["batch_size"] = batch
    res["batch"] = {k: v / batch for k, v in _timed(lambda: index.search(Q32[:batch], 1), 3).items()}
    out.put(res)


def run_default_scale_bench(sizes: list[int], d: int, region_length: int, noise: float,
                            n_queries: int, n_single: int, batch: int, exact_frames: int,
                            out: Path, preset: str = "robust", work_dir: Path | None = None,
                            hnsw_max: int = 200_000, figure: Path | None = None,
                            isolate: bool = True, sweep_noises: tuple[float, ...] = (),
                            also: tuple[str, ...] = ()) -> dict[str, Any]:  # fmt: skip
    """``also``: other presets trained and served on the same route after ``preset`` (the
    default), without the FAISS and exact-NN baselines again (``point["also"][name]``)."""
    points = []
    for n in sizes:
        with tempfile.TemporaryDirectory(prefix="gridplace-scale-", dir=work_dir) as tmp:
            route, registry = str(Path(tmp) / "route.npy"), str(Path(tmp) / "registry")
            with console.status(f"N={n:,}: writing the SYNTHETIC route…"):
                start = time.perf_counter()
                write_route(route, n, d, region_length=region_length, seed=0)
                gen_s = time.perf_counter() - start
            params = {"encoder_preset": preset, "n_jobs": 1}
            noises = list(sweep_noises) or [noise]
            with console.status(f"N={n:,}: training {preset}…"):
                train = _in_child(_train_child, route, registry, params, isolate=isolate)
            with console.status(f"N={n:,}: loading and querying…"):
                serve = _in_child(_serve_child, route, registry, n_queries, n_single, batch, noise,
                                  noises, isolate=isolate)  # fmt: skip
            others: dict[str, Any] = {}
            for name in also:
                other = {"encoder_preset": name, "n_jobs": 1}
                reg = str(Path(tmp) / f"registry-{name}")
                with console.status(f"N={n:,}: training and serving {name}…"):
                    others[name] = {
                        "params": other,
                        "train": _in_child(_train_child, route, reg, other, isolate=isolate),
                        "serve": _in_child(_serve_child, route, reg, n_queries, n_single, batch,
                                           noise, noises, isolate=isolate)}  # fmt: skip
            faiss_res = {}
            for kind in ("ivf_sq8", "hnsw"):
                if kind == "hnsw" and n > hnsw_max:
                    faiss_res[kind] = {"kind": kind, "skipped": f"N > hnsw_max = {hnsw_max:,}"}
                    continue
                with console.status(f"N={n:,}: FAISS {kind}…"):
                    faiss_res[kind] = _in_child(_faiss_child, route, kind, n_queries, n_single,
                                                batch, noise, noises, tmp,
                                                isolate=isolate)  # fmt: skip
            with console.status(f"N={n:,}: exact NN…"):
                exact = _in_child(_exact_child, route, exact_frames, n_queries, noise,
                                  isolate=isolate)  # fmt: skip
        scale = n / exact["frames_measured"]
        exact.update(extrapolated=scale > 1, single_s_at_N=exact["single"]["cpu_s"] * scale,
                     batch_s_at_N=exact["batch"]["cpu_s"] * scale,
                     stored_bytes_at_N=exact["stored_bytes_measured"] * scale)  # fmt: skip
        points.append({"N": n, "d": d, "params": params, "generate_seconds": gen_s,
                       "train": train, "serve": serve, "also": others, "faiss": faiss_res,
                       "exact_nn": exact})  # fmt: skip
        print_point(points[-1])
        _write(out, points, region_length, noise, n_queries)
    report = _write(out, points, region_length, noise, n_queries)
    if figure is not None:
        from service.bench.scale_figure import plot_default_scale

        plot_default_scale(report, figure)
    console.print(f"wrote {out}" + (f" and {figure}" if figure else ""))
    return report


def _write(out: Path, points: list[dict[str, Any]], region_length: int, noise: float,
           n_queries: int) -> dict[str, Any]:  # fmt: skip
    report = {
        "benchmark": "scale (default preset)", "date": datetime.now(UTC).isoformat(),
        "machine": {"cores": os.cpu_count(), "platform": platform.platform(),
                    "note": "2 cores shared with other work; benches run under nice"},
        "data": f"{SYNTHETIC_LABEL}: write_route, region_length={region_length}, "
                f"query noise {noise} on {n_queries} random frames",
        "points": points,
        "notes": "latency medians with one BLAS/OpenMP thread; exact NN measured on the first "
                 "exact_frames frames and scaled linearly to N; the flat scan's batch is "
                 "smaller than the inverted file's (its scores are (batch, N))",
    }  # fmt: skip
    tmp = out.with_suffix(".tmp")
    tmp.write_text(json.dumps(report, indent=2))
    tmp.replace(out)
    return report


def _us(s: float) -> str:
    return f"{s * 1e6:,.0f} µs"


def print_point(p: dict[str, Any]) -> None:
    t, s, e = p["train"], p["serve"], p["exact_nn"]
    table = Table(title=f"N = {p['N']:,}, d = {p['d']}, {p['params']['encoder_preset']} — SYNTHETIC")
    for col in ("", "build s", "peak RSS MB", "stored MB", "load s", "RSS added MB",
                "single", "batch/q", "P@5"):
        table.add_column(col)
    rows = []
    runs = [(p["params"]["encoder_preset"], t, s),
            *((name, o["train"], o["serve"]) for name, o in p.get("also", {}).items())]
    for name, tr, sv in runs:
        for key in ("ivf", "flat"):
            if key in sv:
                rows.append((f"gridplace {name} {key}", f"{tr['train_seconds']:.0f}",
                             tr["peak_rss_bytes"], tr["artifact_bytes"], sv["load_seconds"],
                             sv["rss_after_load_bytes"], sv[key]["single"]["cpu_s"],
                             sv[key]["batch"]["cpu_s"], sv[key]["precision_at_5"]))  # fmt: skip
    for kind, f in p["faiss"].items():
        if "skipped" not in f:
            rows.append((f"FAISS {kind}", f"{f['build_seconds']:.0f}", f["peak_rss_bytes"],
                         f["index_bytes"], f["load_seconds"], f["rss_after_load_bytes"],
                         f["single"]["cpu_s"], f["batch"]["cpu_s"], f["precision_at_5"]))  # fmt: skip
    rows.append(("exact NN", "", 0, e["stored_bytes_at_N"], 0.0, 0, e["single_s_at_N"],
                 e["batch_s_at_N"], e["precision_at_5"]))  # fmt: skip
    for name, build, peak, stored, load, added, single, batch, p5 in rows:
        table.add_row(name, build, f"{peak / 1e6:,.0f}", f"{stored / 1e6:,.1f}", f"{load:.2f}",
                      f"{added / 1e6:,.0f}", _us(single), _us(batch), f"{p5:.3f}")  # fmt: skip
    console.print(table)
    for name, _, sv in runs:
        seq = sv["sequence"]
        console.print(f"{name}: sequence filter per frame: scores "
                      f"{_us(seq['frame_scores']['cpu_s'])}, update "
                      f"{_us(seq['filter_update']['cpu_s'])}")  # fmt: skip

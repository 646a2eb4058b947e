"""Scale benchmark: train and serve one SYNTHETIC map of up to a million frames.

For every route length N: the route is written to disk block by block
(:func:`service.encoding.synthetic.write_route`, float32, memory-mapped: never ``N×d``
float64 in memory), a chunked encoder (``frames_per_chunk`` frames per chunk) is trained on
all cores in a child process and published to a registry, and a fresh child process loads it
and answers noisy queries of random frames. Reported: training time and the peak RSS of the
training process and of every chunk worker, artifact bytes, load time and the memory loading
added (peak and settled), single-query and batch latency of the fast path beside the reference
beam decoder, precision, and exact nearest neighbour's latency and storage on the same route
(measured on the first ``exact_frames`` frames and scaled linearly in N where N is larger —
its cost is one product with every stored frame, so linear is exact up to cache effects).

Query timings use one BLAS thread (the serving configuration on a shared machine); each
figure is the median of its repetitions and is given as wall and CPU (thread) time, which
stays meaningful when other work shares the cores.
"""

from __future__ import annotations

import json
import multiprocessing as mp
import os
import platform
import queue
import tempfile
import time
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np
from rich.console import Console
from rich.table import Table

from service.encoding.synthetic import SYNTHETIC_LABEL, route_queries, write_route

console = Console()


def peak_rss_bytes(pid: int | str = "self") -> int:
    """``VmHWM`` (peak resident set) of a process, from ``/proc`` (Linux)."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) * 1024
    return 0


def rss_bytes(pid: int | str = "self") -> int:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) * 1024
    return 0


def _timed(fn: Any, reps: int) -> dict[str, float]:
    """Median wall and thread-CPU seconds of ``fn()`` over ``reps`` calls (after one warm-up)."""
    fn()
    wall, cpu = [], []
    for _ in range(reps):
        w, c = time.perf_counter(), time.thread_time()
        fn()
        cpu.append(time.thread_time() - c)
        wall.append(time.perf_counter() - w)
    return {"wall_s": float(np.median(wall)), "cpu_s": float(np.median(cpu)),
            "wall_p99_s": float(np.percentile(wall, 99))}  # fmt: skip


def _timed_alternating(fns: dict[str, Any], reps: int) -> dict[str, dict[str, float]]:
    """:func:`_timed` of several functions called in turn, so that all see the same load."""
    for fn in fns.values():
        fn()
    wall: dict[str, list[float]] = {k: [] for k in fns}
    cpu: dict[str, list[float]] = {k: [] for k in fns}
    for _ in range(reps):
        for key, fn in fns.items():
            w, c = time.perf_counter(), time.thread_time()
            fn()
            cpu[key].append(time.thread_time() - c)
            wall[key].append(time.perf_counter() - w)
    return {k: {"wall_s": float(np.median(wall[k])), "cpu_s": float(np.median(cpu[k])),
                "wall_p99_s": float(np.percentile(wall[k], 99))} for k in fns}  # fmt: skip


# -- child processes ---------------------------------------------------------------------
def _train_child(route: str, registry: str, params: dict[str, Any], out: Any) -> None:
    import psutil

    from service.encoding import ModelParams, build_model
    from service.registry import Registry

    X = np.load(route, mmap_mode="r")
    start = time.perf_counter()
    model = build_model(ModelParams.parse(**params)).fit(X)
    seconds = time.perf_counter() - start
    workers = [{"pid": c.pid, "peak_rss_bytes": peak_rss_bytes(c.pid)}
               for c in psutil.Process().children(recursive=True) if c.is_running()]  # fmt: skip
    info = Registry(Path(registry)).publish("scale", model, params=params, extractor=None, metrics={})
    out.put({"train_seconds": seconds, "peak_rss_bytes": peak_rss_bytes(),
             "workers": workers, "artifact_bytes": info.artifact_bytes,
             "footprint": info.footprint})  # fmt: skip


def _serve_child(route: str, registry: str, n_queries: int, n_single: int, batch: int,
                 noise: float, out: Any) -> None:  # fmt: skip
    from threadpoolctl import threadpool_limits

    from service.encoding import precision_at
    from service.encoding.decoding import reference_localize
    from service.encoding import check_descriptors
    from service.encoding.serving_plan import ServingPlan, plan_for
    from service.registry import Registry

    X = np.load(route, mmap_mode="r")
    rows = np.sort(np.random.default_rng(7).choice(X.shape[0], n_queries, replace=False))
    Q = route_queries(X, rows, noise, seed=1).astype(np.float64)
    del X
    Path("/proc/self/clear_refs").write_text("5")  # peak RSS := current RSS (Linux)
    base_rss, base_peak = rss_bytes(), peak_rss_bytes()
    start = time.perf_counter()
    model = Registry(Path(registry)).load_model("scale", 1)
    plan = plan_for(model)
    load_s = time.perf_counter() - start
    res: dict[str, Any] = {"load_seconds": load_s, "rss_after_load_bytes": rss_bytes() - base_rss,
                           "peak_during_load_bytes": max(0, peak_rss_bytes() - base_peak)}  # fmt: skip
    with threadpool_limits(1):
        loc = model.localize(Q)
        d = plan.decode(Q)
        res["precision_at_0"] = precision_at(loc.index, rows, 0)
        res["precision_at_5"] = precision_at(loc.index, rows, 5)
        res["rescored_fraction"] = float(d.rescored.mean())
        ref_index, _, _ = reference_localize(model, Q[:batch])
        res["agreement_with_reference"] = float(np.mean(ref_index == loc.index[:batch]))
        singles = iter(range(10**9))
        batch_path = ServingPlan(model)  # the same plan without its one-query path (before)
        batch_path._single = None

        def one_by_batch_path() -> Any:
            q = Q[next(singles) % n_queries][None, :]
            return batch_path.localize(check_descriptors(q, n_features=model.n_features_in_))

        res.update(_timed_alternating({
            "single": lambda: model.localize(Q[next(singles) % n_queries][None, :]),
            "single_batch_path": one_by_batch_path}, n_single))  # fmt: skip
        res["single_reference"] = _timed(
            lambda: reference_localize(model, Q[next(singles) % n_queries][None, :]), n_single // 4
        )
        res["batch"] = {k: v / batch for k, v in _timed(lambda: model.localize(Q[:batch]), 5).items()}
        res["batch_reference"] = {
            k: v / batch for k, v in _timed(lambda: reference_localize(model, Q[:batch]), 2).items()
        }
    res["process_peak_rss_bytes"] = peak_rss_bytes()
    out.put(res)


def _exact_child(route: str, frames: int, n_queries: int, noise: float, out: Any) -> None:
    from threadpoolctl import threadpool_limits

    from service.encoding import ExactNN, precision_at

    X = np.load(route, mmap_mode="r")
    m = min(frames, X.shape[0])
    rows = np.sort(np.random.default_rng(7).choice(m, min(n_queries, m), replace=False))
    Q = route_queries(X, rows, noise, seed=1).astype(np.float64)
    nn = ExactNN().fit(np.asarray(X[:m]))
    with threadpool_limits(1):
        single = _timed(lambda: nn.localize(Q[:1]), 20)
        batch = {k: v / 256 for k, v in _timed(lambda: nn.localize(Q[:256]), 3).items()}
        p5 = precision_at(nn.localize(Q[:256]).index, rows[:256], 5)
    out.put({"frames_measured": m, "single": single, "batch": batch, "precision_at_5": p5,
             "stored_bytes_measured": int(nn.footprint().actual_bytes)})  # fmt: skip


def _in_child(target: Any, *args: Any, isolate: bool = True) -> dict[str, Any]:
    """Run ``target(*args, queue)`` in a fresh (spawned) process and return what it puts
    (``isolate=False``: in this process, for a quick check of the figures' plumbing)."""
    if not isolate:
        q: queue.SimpleQueue[dict[str, Any]] = queue.SimpleQueue()
        target(*args, q)
        return q.get_nowait()
    ctx = mp.get_context("spawn")
    mq = ctx.Queue()
    proc = ctx.Process(target=target, args=(*args, mq))
    proc.start()
    try:
        while True:
            try:
                return mq.get(timeout=1.0)  # type: ignore[no-any-return]
            except queue.Empty:
                if not proc.is_alive():
                    raise RuntimeError(
                        f"{target.__name__} exited with {proc.exitcode} without a result"
                    ) from None
    finally:
        proc.join(60)
        if proc.is_alive():  # its result is in; do not leave it (or its workers) behind
            proc.terminate()
            proc.join(10)


# -- the benchmark ---------------------------------------------------------------------
def run_scale_bench(sizes: list[int], d: int, frames_per_chunk: int, region_length: int,
                    noise: float, n_queries: int, n_single: int, batch: int, exact_frames: int,
                    trainer: str, out: Path, work_dir: Path | None = None,
                    figure: Path | None = None, isolate: bool = True,
                    preset: str = "ridge") -> dict[str, Any]:  # fmt: skip
    points = []
    for n in sizes:
        with tempfile.TemporaryDirectory(prefix="gridplace-scale-", dir=work_dir) as tmp:
            route = str(Path(tmp) / "route.npy")
            registry = str(Path(tmp) / "registry")
            with console.status(f"N={n:,}: writing the SYNTHETIC route…"):
                start = time.perf_counter()
                write_route(route, n, d, region_length=region_length, seed=0)
                gen_s = time.perf_counter() - start
            params = {"encoder_preset": preset, "trainer": trainer, "n_patterns": 2, "rho": 0.5,
                      "n_chunks": max(1, n // frames_per_chunk), "n_jobs": -1}  # fmt: skip
            with console.status(f"N={n:,}: training {params['n_chunks']} chunks on all cores…"):
                train = _in_child(_train_child, route, registry, params, isolate=isolate)
            with console.status(f"N={n:,}: loading and querying…"):
                serve = _in_child(_serve_child, route, registry, n_queries, n_single, batch, noise,
                                  isolate=isolate)  # fmt: skip
            with console.status(f"N={n:,}: exact NN…"):
                exact = _in_child(_exact_child, route, exact_frames, n_queries, noise,
                                  isolate=isolate)  # fmt: skip
        scale = n / exact["frames_measured"]
        exact["extrapolated"] = scale > 1
        exact["single_s_at_N"] = exact["single"]["cpu_s"] * scale
        exact["batch_s_at_N"] = exact["batch"]["cpu_s"] * scale
        exact["stored_bytes_at_N"] = exact["stored_bytes_measured"] * scale
        points.append({"N": n, "d": d, "params": params, "generate_seconds": gen_s,
                       "train": train, "serve": serve, "exact_nn": exact})  # fmt: skip
        _print_point(points[-1])
    report = {
        "benchmark": "scale",
        "date": datetime.now(UTC).isoformat(),
        "machine": {"cores": os.cpu_count(), "platform": platform.platform()},
        "data": f"{SYNTHETIC_LABEL}: write_route, region_length={region_length}, "
                f"query noise {noise} on {n_queries} random frames",
        "points": points,
        "notes": "query latency medians with one BLAS thread; exact NN measured on the first "
                 "exact_frames frames and scaled linearly to N where N is larger",
    }  # fmt: skip
    out.write_text(json.dumps(report, indent=2))
    if figure is not None:
        plot_scale(report, figure)
    console.print(f"wrote {out}" + (f" and {figure}" if figure else ""))
    return report


def plot_scale(report: dict[str, Any], path: Path) -> None:
    """Query time against N: gridplace (fast path and reference decoder) and exact NN."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    pts = report["points"]
    ns = [p["N"] for p in pts]
    fig, ax = plt.subplots(figsize=(6.4, 4.4))
    series = (
        ("gridplace, single query", [p["serve"]["single"]["cpu_s"] for p in pts], "-o"),
        ("gridplace, batch (per query)", [p["serve"]["batch"]["cpu_s"] for p in pts], "-s"),
        ("reference decoder, single", [p["serve"]["single_reference"]["cpu_s"] for p in pts], ":o"),
        ("exact NN, single query", [p["exact_nn"]["single_s_at_N"] for p in pts], "--o"),
        ("exact NN, batch (per query)", [p["exact_nn"]["batch_s_at_N"] for p in pts], "--s"),
    )  # fmt: skip
    for label, secs, style in series:
        ax.plot(ns, np.asarray(secs) * 1e6, style, label=label)
    ax.set(xscale="log", yscale="log", xlabel="route length N (frames)",
           ylabel="CPU time per query (µs)",
           title=f"Query time against N (SYNTHETIC, d={pts[0]['d']})")  # fmt: skip
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _mb(b: float) -> str:
    return f"{b / 1e6:,.1f} MB"


def _us(s: float) -> str:
    return f"{s * 1e6:,.0f} µs"


def _print_point(p: dict[str, Any]) -> None:
    t, s, e = p["train"], p["serve"], p["exact_nn"]
    table = Table(title=f"N = {p['N']:,} frames, d = {p['d']}, {p['params']['n_chunks']} chunks "
                        f"({p['params']['trainer']}) — SYNTHETIC")  # fmt: skip
    table.add_column("measure")
    table.add_column("gridplace")
    table.add_column("before (reference decoder) / exact NN")
    table.add_row("training time", f"{t['train_seconds']:.1f} s", "")
    workers = max((w["peak_rss_bytes"] for w in t["workers"]), default=0)
    table.add_row("peak RSS: training process / largest of "
                  f"{len(t['workers'])} workers", f"{_mb(t['peak_rss_bytes'])} / {_mb(workers)}", "")  # fmt: skip
    table.add_row("artifact / exact NN storage", _mb(t["artifact_bytes"]),
                  _mb(e["stored_bytes_at_N"]) + (" (scaled)" if e["extrapolated"] else ""))  # fmt: skip
    table.add_row("load time / memory added (settled, peak)", f"{s['load_seconds']:.2f} s / "
                  f"{_mb(s['rss_after_load_bytes'])}, {_mb(s['peak_during_load_bytes'])}", "")  # fmt: skip
    table.add_row("single query (CPU, median)", _us(s["single"]["cpu_s"]),
                  f"{_us(s['single_reference']['cpu_s'])} / {_us(e['single_s_at_N'])}")  # fmt: skip
    if "single_batch_path" in s:
        table.add_row("single query through the batch path (CPU, median)",
                      _us(s["single_batch_path"]["cpu_s"]), "")  # fmt: skip
    table.add_row("single query (wall, median / p99)",
                  f"{_us(s['single']['wall_s'])} / {_us(s['single']['wall_p99_s'])}", "")  # fmt: skip
    table.add_row("batch, per query (CPU)", _us(s["batch"]["cpu_s"]),
                  f"{_us(s['batch_reference']['cpu_s'])} / {_us(e['batch_s_at_N'])}")  # fmt: skip
    table.add_row("precision @0 / @5", f"{s['precision_at_0']:.3f} / {s['precision_at_5']:.3f}",
                  f"exact NN @5 on its {e['frames_measured']:,} frames: {e['precision_at_5']:.3f}")  # fmt: skip
    table.add_row("answers equal to the reference decoder", f"{s['agreement_with_reference']:.4f}",
                  f"re-scored in float64: {s['rescored_fraction']:.3%}")  # fmt: skip
    console.print(table)

"""Serving benchmark: a real ``gridplace serve`` on loopback holding a 10k-frame map.

Measures single-descriptor ``POST /v1/localize`` latency (p50/p99, client round trip and the
server's own ``latency_ms``) and batch throughput (queries/s, binary float32 bodies), with the
in-process encoder's time for the same queries beside them, so the HTTP overhead is visible.

Data: the real Nordland route (summer reference, winter queries, 3,576 frames, 64×32
patch-normalised) tiled to ``n_frames`` with a little per-copy noise (AUGMENTED: copies of the
same places, so precision is reported per place, i.e. modulo 3,576), or a SYNTHETIC smooth
route when the Nordland files are not present. The output says which.
"""

from __future__ import annotations

import base64
import contextlib
import io
import json
import os
import platform
import secrets
import tempfile
import time
from collections import defaultdict
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import orjson
from rich.console import Console
from rich.table import Table

from service.api.process import ServerProcess
from service.bench.data import nordland
from service.encoding.decoding import reference_localize
from service.encoding.synthetic import smooth_route
from service.errors import UnavailableError

console = Console()


def bench_data(n_frames: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray, int, str]:
    """Reference, queries (query i ↔ place i mod period), period, label."""
    real = nordland()
    if real is None:
        synth = smooth_route(n_frames, 2048, seed=seed)
        return synth.reference, synth.query, n_frames, f"{synth.label}, {n_frames}x2048"
    base_n = real.reference.shape[0]
    reps = -(-n_frames // base_n)
    rng = np.random.default_rng(seed)
    noise = 0.05 * rng.standard_normal((reps * base_n, real.reference.shape[1])).astype(np.float32)
    ref = (np.concatenate([real.reference] * reps) + noise)[:n_frames]
    qry = np.concatenate([real.query] * reps)[:n_frames]
    label = (f"REAL Nordland summer reference / winter queries ({base_n} frames, 64x32 "
             f"patch-normalised) AUGMENTED: tiled x{reps} with N(0, 0.05) noise to {n_frames} frames")  # fmt: skip
    return ref.astype(np.float32), qry.astype(np.float32), base_n, label


def _pct(values: list[float]) -> dict[str, float]:
    a = np.asarray(values)
    return {"p50": float(np.percentile(a, 50)), "p90": float(np.percentile(a, 90)),
            "p99": float(np.percentile(a, 99)), "mean": float(a.mean()), "n": int(a.size)}  # fmt: skip


def _train(c: httpx.Client, auth: dict[str, str], X: np.ndarray, params: dict[str, str]) -> dict[str, Any]:
    buf = io.BytesIO()
    np.save(buf, X, allow_pickle=False)
    start = time.perf_counter()
    r = c.post("/v1/maps/bench/routes", headers=auth, files={"file": ("route.npy", buf.getvalue())},
               data=params, timeout=600)  # fmt: skip
    if r.status_code != 202:
        raise UnavailableError(f"upload refused: {r.status_code} {r.text}")
    job_id = r.json()["id"]
    with console.status("training the 10k-frame map on the server…"):
        while True:
            job = c.get(f"/v1/jobs/{job_id}", headers=auth).json()
            if job["state"] in ("succeeded", "failed"):
                break
            time.sleep(0.5)
    if job["state"] != "succeeded":
        raise UnavailableError(f"training failed: {job['error']}")
    job["upload_to_done_seconds"] = time.perf_counter() - start
    return job  # type: ignore[no-any-return]


def _single(c: httpx.Client, Q: np.ndarray, n: int, as_b64: bool, raw: bool = False) -> dict[str, Any]:
    """Sequential single requests; the client's time includes encoding the JSON body (orjson:
    the stdlib ``json`` alone takes ~0.8 ms for 2,048 floats, see ``client_encode_ms``)."""
    client_ms: list[float] = []
    server_ms: list[float] = []
    answers: list[int] = []
    headers = {"Content-Type": "application/json"}
    for i in range(n + 20):
        q = Q[i % Q.shape[0]]
        start = time.perf_counter()
        body: dict[str, Any] = {"map": "bench"}
        if as_b64:
            body["descriptor_b64"] = base64.b64encode(q.astype("<f4").tobytes()).decode()
        else:
            body["descriptor"] = q.tolist()
        r = c.post("/v1/localize", content=orjson.dumps(body), headers=headers)
        elapsed = (time.perf_counter() - start) * 1000
        r.raise_for_status()
        if i >= 20:  # warm-up excluded
            client_ms.append(elapsed)
            server_ms.append(r.json()["latency_ms"])
            answers.append(r.json()["index"])
    if raw:
        return {"client_raw": client_ms, "server_raw": server_ms, "answers": answers}
    return {"client_ms": _pct(client_ms), "server_ms": _pct(server_ms), "answers": answers}


def _batch(c: httpx.Client, Q: np.ndarray, batch: int) -> dict[str, Any]:
    c.post("/v1/localize/batch?map=bench", content=Q[:batch].astype("<f4").tobytes(),
           headers={"Content-Type": "application/octet-stream"}).raise_for_status()  # fmt: skip
    index: list[int] = []
    start = time.perf_counter()
    for s in range(0, Q.shape[0], batch):
        r = c.post("/v1/localize/batch?map=bench", content=Q[s : s + batch].astype("<f4").tobytes(),
                   headers={"Content-Type": "application/octet-stream"})  # fmt: skip
        r.raise_for_status()
        index += r.json()["index"]
    seconds = time.perf_counter() - start
    return {"batch_size": batch, "queries": Q.shape[0], "seconds": seconds,
            "queries_per_s": Q.shape[0] / seconds, "index": index}  # fmt: skip


def _in_process(localize: Any, Q: np.ndarray, n_single: int, batch: int) -> dict[str, Any]:
    """Single and batch timing in this process with one BLAS thread, as the server runs
    (``GRIDPLACE_SERVE_BLAS_THREADS=1``; more threads thrash on shared cores)."""
    from threadpoolctl import threadpool_limits

    with threadpool_limits(1):
        return _timed_in_process(localize, Q, n_single, batch)


def _timed_in_process(localize: Any, Q: np.ndarray, n_single: int, batch: int) -> dict[str, Any]:
    ms = []
    for i in range(n_single + 20):
        start = time.perf_counter()
        localize(Q[i % Q.shape[0]][None, :])
        if i >= 20:
            ms.append((time.perf_counter() - start) * 1000)
    start = time.perf_counter()
    for s in range(0, Q.shape[0], batch):
        localize(Q[s : s + batch])
    seconds = time.perf_counter() - start
    return {"single_ms": _pct(ms), "batch_queries_per_s": Q.shape[0] / seconds}


def _client_encode(Q: np.ndarray) -> dict[str, float]:
    """What encoding one JSON-floats body costs a client (stdlib json vs orjson), in ms."""
    body = {"map": "bench", "descriptor": Q[0].tolist()}
    out = {}
    for name, dumps in (("json", lambda b: json.dumps(b).encode()), ("orjson", orjson.dumps)):
        start = time.perf_counter()
        for _ in range(200):
            dumps(body)
        out[name] = (time.perf_counter() - start) / 200 * 1000
    return out


def _merge(parts: list[dict[str, Any]]) -> dict[str, Any]:
    """One figure from rounds of :func:`_single` or :func:`_batch`."""
    if "queries_per_s" in parts[0]:
        seconds = sum(p["seconds"] for p in parts)
        queries = sum(p["queries"] for p in parts)
        return {"batch_size": parts[0]["batch_size"], "queries": queries, "seconds": seconds,
                "queries_per_s": queries / seconds, "index": [i for p in parts for i in p["index"]]}  # fmt: skip
    return {"client_ms": _pct([x for p in parts for x in p["client_raw"]]),
            "server_ms": _pct([x for p in parts for x in p["server_raw"]]),
            "answers": [a for p in parts for a in p["answers"]]}  # fmt: skip


def _rest(data_dir: Path, env: dict[str, str], qry: np.ndarray, Qb: np.ndarray, n_single: int,
          batch: int, compare: bool, rounds: int = 5) -> list[dict[str, Any]]:  # fmt: skip
    """The micro-batched server (and, with ``compare``, one without batching, up at the same
    time): each measure runs in ``rounds`` alternating rounds, so both see the same load."""
    modes = [True, False] if compare else [True]
    with contextlib.ExitStack() as stack:
        clients = []
        for batching in modes:
            srv = stack.enter_context(ServerProcess(
                data_dir, env={**env, "GRIDPLACE_BATCHING": "true" if batching else "false"}))
            srv.wait_ready(120)
            clients.append(stack.enter_context(httpx.Client(base_url=srv.url, timeout=60)))
        parts: list[dict[str, list[dict[str, Any]]]] = [defaultdict(list) for _ in modes]
        per = max(1, n_single // rounds)
        for _ in range(rounds):
            for c, got in zip(clients, parts, strict=True):
                got["single_json"].append(_single(c, qry, per, as_b64=False, raw=True))
                got["single_b64"].append(_single(c, qry, per, as_b64=True, raw=True))
                got["batch_binary"].append(_batch(c, Qb, batch))
    return [{"batching": b, **{k: _merge(v) for k, v in got.items()}}
            for b, got in zip(modes, parts, strict=True)]  # fmt: skip


def run_serve_bench(n_frames: int, n_single: int, n_batch_queries: int, batch: int,
                    params: dict[str, str], out: Path, compare: bool = True) -> dict[str, Any]:  # fmt: skip
    ref, qry, period, label = bench_data(n_frames)
    token = secrets.token_hex(16)
    auth = {"Authorization": f"Bearer {token}"}
    upload_mb = str(max(64, ref.nbytes // (1024 * 1024) * 2))
    env = {"GRIDPLACE_ADMIN_TOKEN": token, "GRIDPLACE_MAX_UPLOAD_MB": upload_mb,
           "GRIDPLACE_TRAIN_WORKERS": "1", "GRIDPLACE_LOG_LEVEL": "warning"}  # fmt: skip
    Qb = qry[:n_batch_queries]
    with tempfile.TemporaryDirectory(prefix="gridplace-bench-") as tmp:
        data_dir = Path(tmp)
        with ServerProcess(data_dir, env=env) as srv, httpx.Client(base_url=srv.url, timeout=60) as c:
            job = _train(c, auth, ref, params)
            srv.wait_ready(120)
            version = c.get("/v1/maps/bench/versions/1", headers=auth).json()
        runs = _rest(data_dir, env, qry, Qb, n_single, batch, compare)
        from service.registry import Registry

        model = Registry(data_dir).load_model("bench", 1)
        local = _in_process(model.localize, qry, n_single, batch)
        reference = _in_process(lambda Q: reference_localize(model, Q), qry, n_single, batch)
    truth = np.arange(Qb.shape[0]) % period
    main = runs[0]
    first = np.asarray(main["batch_binary"]["index"][: Qb.shape[0]])  # every round sends Qb
    place_p5 = float(np.mean(np.abs(first % period - truth) <= 5))
    same = None
    if compare:
        same = (main["single_json"]["answers"] == runs[1]["single_json"]["answers"]
                and main["batch_binary"]["index"] == runs[1]["batch_binary"]["index"])  # fmt: skip
    for r in runs:
        for key in ("single_json", "single_b64"):
            r[key].pop("answers")
        r["batch_binary"].pop("index")
    report: dict[str, Any] = {
        "benchmark": "serve",
        "date": datetime.now(UTC).isoformat(),
        "machine": {"cores": os.cpu_count(), "platform": platform.platform()},
        "data": {"label": label, "N": int(ref.shape[0]), "d": int(ref.shape[1])},
        "params": params,
        "model": {
            "kind": version["kind"],
            "footprint": version["footprint"],
            "artifact_bytes": version["artifact_bytes"],
        },
        "training": {"upload_to_done_seconds": job["upload_to_done_seconds"], "timings": job["timings"]},
        **{k: v for k, v in main.items() if k != "batching"},
        "unbatched": runs[1] if compare else None,
        "batched_answers_equal_unbatched": same,
        "in_process": local,
        "in_process_reference_decoder": reference,
        "client_encode_ms": _client_encode(qry),
        "place_precision_at_5_winter_queries": place_p5,
        "transport": "HTTP/1.1 keep-alive on loopback, one client, httpx; JSON bodies encoded "
                     "with orjson inside the timed request",
    }
    _print(report)
    out.write_text(json.dumps(report, indent=2))
    console.print(f"wrote {out}")
    return report


def _print(r: dict[str, Any]) -> None:
    console.print(f"[bold]data:[/] {r['data']['label']} (N={r['data']['N']}, d={r['data']['d']})")
    runs = [r] + ([r["unbatched"]] if r.get("unbatched") else [])
    t = Table(title="gridplace serve — loopback (micro-batched | unbatched)")
    for col in ("measure", "p50", "p99", "throughput"):
        t.add_column(col)
    for name, key in (("single /localize JSON floats", "single_json"),
                      ("single /localize base64", "single_b64")):  # fmt: skip
        for side in ("client", "server"):
            t.add_row(f"{name}: {side} ms",
                      " | ".join(f"{x[key][f'{side}_ms']['p50']:.2f}" for x in runs),
                      " | ".join(f"{x[key][f'{side}_ms']['p99']:.2f}" for x in runs),
                      " | ".join(f"{1000 / x[key][f'{side}_ms']['mean']:.0f} req/s" for x in runs)
                      if side == "client" else "")  # fmt: skip
    b = r["batch_binary"]
    t.add_row(f"batch /localize/batch binary ×{b['batch_size']}", "", "",
              " | ".join(f"{x['batch_binary']['queries_per_s']:.0f} q/s" for x in runs))  # fmt: skip
    for name, key in (("in-process fast path", "in_process"),
                      ("in-process reference decoder", "in_process_reference_decoder")):  # fmt: skip
        loc = r[key]
        t.add_row(f"{name}, 1 descriptor: ms", f"{loc['single_ms']['p50']:.3f}",
                  f"{loc['single_ms']['p99']:.3f}", f"{1000 / loc['single_ms']['mean']:.0f} q/s")  # fmt: skip
        t.add_row(f"{name}, batch ×{b['batch_size']}", "", "", f"{loc['batch_queries_per_s']:.0f} q/s")
    console.print(t)
    enc = r["client_encode_ms"]
    console.print(f"client JSON encoding of one descriptor: json {enc['json']:.2f} ms, orjson "
                  f"{enc['orjson']:.2f} ms; answers identical batched and unbatched: "
                  f"{r['batched_answers_equal_unbatched']}")  # fmt: skip
    p5 = r["place_precision_at_5_winter_queries"]
    console.print(f"place precision@5 of the batch answers (winter queries, cross-season): {p5:.3f}; "
                  f"training (upload → done): {r['training']['upload_to_done_seconds']:.1f} s")  # fmt: skip

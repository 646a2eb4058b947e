"""``gridplace bench workers``: a chunked route trained by RQ workers on a PostgreSQL registry.

Starts its own ``redis-server`` (free port, nothing persisted), uses the registry at
``--registry-url`` or a scratch PostgreSQL database (created and dropped), and trains the
same route with 1 and then with N ``gridplace worker`` processes, in one run: wall time from
submit to the published version, the speed-up, the chunk parts' own seconds, and how long
registry operations take on PostgreSQL beside the embedded SQLite file.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from service.api.process import free_port
from service.encoding import ModelParams, build_model
from service.errors import UnavailableError
from service.jobs.rq_backend import RQBackend
from service.registry import Registry
from service.registry.scratch import ScratchDatabase
from service.settings import Settings


def _redis() -> tuple[subprocess.Popen[bytes], str]:
    exe = shutil.which("redis-server")
    if exe is None:
        raise UnavailableError("bench workers needs redis-server on PATH")
    port = free_port()
    proc = subprocess.Popen([exe, "--port", str(port), "--bind", "127.0.0.1", "--save", "",
                             "--appendonly", "no"], stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)  # fmt: skip
    from redis import Redis
    from redis.exceptions import RedisError

    url = f"redis://127.0.0.1:{port}/0"
    client = Redis.from_url(url)
    for _ in range(200):
        try:
            client.ping()
            return proc, url
        except RedisError:
            time.sleep(0.05)
    proc.kill()
    raise UnavailableError("redis-server did not start")


def _train(data_dir: Path, route: Path, params: ModelParams, redis_url: str, registry_url: str,
           n_workers: int, name: str) -> dict[str, Any]:  # fmt: skip
    queue = f"bench-{name}"
    env = {**os.environ, "GRIDPLACE_REGISTRY_URL": registry_url}
    workers = [subprocess.Popen(
        [sys.executable, "-m", "service.cli", "worker", "--redis-url", redis_url, "--queue",
         queue, "--name", f"{queue}-{i}"], env=env, start_new_session=True,
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL) for i in range(n_workers)]  # fmt: skip
    registry = Registry(data_dir, url=registry_url)
    backend = RQBackend(Settings(data_dir=data_dir, redis_url=redis_url, queue_name=queue,
                                 reconcile_interval_s=0), registry)  # fmt: skip
    try:
        time.sleep(2.0)  # workers register with Redis
        start = time.perf_counter()
        job = backend.submit(name, route, params, None, None)
        while not (job := backend.get_job(job.id)).done:
            time.sleep(0.1)
        wall = time.perf_counter() - start
        if job.state != "succeeded":
            raise UnavailableError(f"bench training failed: {job.error}")
        chunk_s = [v for k, v in job.timings.items() if k.startswith("chunk_")]
        return {"workers": n_workers, "wall_seconds": wall, "version": job.version,
                "chunk_seconds_sum": float(sum(chunk_s)), "parts": len(chunk_s),
                "retries": len(job.retries)}  # fmt: skip
    finally:
        backend.close()
        registry.close()
        for w in workers:
            os.killpg(w.pid, signal.SIGTERM)
        for w in workers:
            try:
                w.wait(30)
            except subprocess.TimeoutExpired:
                os.killpg(w.pid, signal.SIGKILL)
                w.wait()


def _registry_ops(data_dir: Path, url: str | None, model: Any, n: int = 20) -> dict[str, float]:
    """Median milliseconds of a publish, an activation and a generation poll."""
    reg = Registry(data_dir, url=url)
    pub, act, gen = [], [], []
    for _ in range(n):
        t = time.perf_counter()
        v = reg.publish("ops", model, params={}, extractor=None, metrics={}).version
        pub.append(time.perf_counter() - t)
        t = time.perf_counter()
        reg.activate("ops", v)
        act.append(time.perf_counter() - t)
        t = time.perf_counter()
        reg.generation()
        gen.append(time.perf_counter() - t)
    reg.close()
    med = lambda xs: float(np.median(xs) * 1000)  # noqa: E731
    return {"publish_ms": med(pub), "activate_ms": med(act), "generation_poll_ms": med(gen)}


def run_workers_bench(n_frames: int, n_features: int, chunks: int, workers: int, trainer: str,
                      registry_url: str | None, out: Path) -> dict[str, Any]:  # fmt: skip
    from service.bench.data import nordland
    from service.encoding.synthetic import smooth_route

    real = nordland(limit=n_frames)
    if real is not None:
        X, source = real.reference, real.label
    else:
        X = smooth_route(n_frames, n_features, seed=0).reference
        source = f"SYNTHETIC smooth route {n_frames}x{n_features} (no Nordland data found)"
    params = ModelParams.parse(trainer=trainer, n_chunks=chunks)
    tmp = Path(tempfile.mkdtemp(prefix="gridplace-bench-workers-"))
    scratch = None if registry_url else ScratchDatabase(prefix="gridplace_bench")
    url = registry_url or scratch.create()  # type: ignore[union-attr]
    redis, redis_url = _redis()
    try:
        route = tmp / "uploads" / "route.npy"
        route.parent.mkdir(parents=True)
        np.save(route, X.astype(np.float32))
        one = _train(tmp, route, params, redis_url, url, 1, "one")
        many = _train(tmp, route, params, redis_url, url, workers, "many")
        small = build_model(ModelParams.parse(trainer="ridge")).fit(X[:200])
        ops = {"postgresql": _registry_ops(tmp / "pg", url, small),
               "sqlite": _registry_ops(tmp / "sqlite", "sqlite:///" + str(tmp / "r.sqlite3"),
                                       small)}  # fmt: skip
    finally:
        redis.terminate()
        redis.wait(10)
        if scratch is not None:
            scratch.drop()
        shutil.rmtree(tmp, ignore_errors=True)
    result = {"data": source, "n_frames": int(X.shape[0]), "n_features": int(X.shape[1]),
              "n_chunks": chunks, "trainer": trainer, "registry": "postgresql",
              "one_worker": one, "n_workers": many,
              "speedup": one["wall_seconds"] / many["wall_seconds"], "registry_ops": ops}  # fmt: skip
    out.write_text(json.dumps(result, indent=2))
    print(f"{source}: N={X.shape[0]} d={X.shape[1]} chunks={chunks} trainer={trainer}, "
          f"registry on PostgreSQL")
    print(f"  1 worker : {one['wall_seconds']:.1f} s submit→published")
    print(f"  {workers} workers: {many['wall_seconds']:.1f} s  (speed-up {result['speedup']:.2f}x, "
          f"chunk parts {many['chunk_seconds_sum']:.1f} s of work, {many['retries']} retries)")
    for kind, o in ops.items():
        print(f"  registry {kind:10s}: publish {o['publish_ms']:.1f} ms, activate "
              f"{o['activate_ms']:.2f} ms, generation poll {o['generation_poll_ms']:.2f} ms")
    print(f"  → {out}")
    return result

"""The least CPU a fleet's frame can cost a server on this transport, measured in process.

A stream frame's server CPU is the transport's share (what the do-nothing server of
:mod:`service.bench.grpc_floor` spends per frame) plus the work no server can skip: adapting
the frame to its vehicle's appearance statistics and localizing it. :func:`compute_per_frame`
times that work alone — the vectorised adaptation step of every vehicle of a batch
(:func:`~service.encoding.adaptation.transform_rows`) and one ``localize`` of the batch, on
one BLAS thread as the server runs — at the largest batch the fleet can form (every frame in
flight at once: ``streams × window``, which makes per-frame costs the smallest), with no
validation, queueing, answers or metrics. So ``1 + compute / floor`` is a lower bound of
gridplace's server CPU per frame against the floor's (:func:`lower_bound_ratio`), whatever
the server's own code does: ``gridplace bench grpc`` reports it beside the measured ratio.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from service.encoding.adaptation import AdaptationConfig, AppearanceAdapter, transform_rows


def compute_per_frame(model: Any, queries: np.ndarray, n_streams: int, window: int,
                      adaptation: AdaptationConfig | None = None, adapt: bool = True,
                      rounds: int = 20, seconds: float = 2.0) -> dict[str, Any]:  # fmt: skip
    """CPU µs per frame of adapting (``adapt``) and localizing batches of ``n_streams``
    vehicles × ``window`` frames of ``queries`` (float32 rows, one vehicle's drive per stream,
    as the benchmark's streams send them; unadapted frames are localized as sent); the best
    of ``rounds`` batches, or of as many as ``seconds`` allow: the figure least inflated by
    other load on shared cores."""
    from threadpoolctl import threadpool_limits

    if n_streams < 1 or window < 1:
        raise ValueError("n_streams and window must be at least 1")
    Q = np.ascontiguousarray(queries, dtype=np.float32)
    per = max(1, Q.shape[0] // n_streams)
    adapters = [AppearanceAdapter.for_model(model, adaptation) for _ in range(n_streams)]
    order = [adapters[s] for _ in range(window) for s in range(n_streams)]
    size = n_streams * window
    best_adapt = best_localize = float("inf")
    with threadpool_limits(1, user_api="blas"):
        deadline = time.perf_counter() + seconds
        for r in range(rounds + 1):  # the first round warms the caches and is not counted
            rows = [Q[(s * per + r * window + j) % Q.shape[0]] for j in range(window)
                    for s in range(n_streams)]  # fmt: skip
            start = time.thread_time()
            X = np.stack(transform_rows(order, rows) if adapt else rows)
            adapted = time.thread_time()
            model.localize(X)
            done = time.thread_time()
            if r:
                best_adapt = min(best_adapt, adapted - start)
                best_localize = min(best_localize, done - adapted)
            if r and time.perf_counter() > deadline:
                break
    adapt_us, localize_us = 1e6 * best_adapt / size, 1e6 * best_localize / size
    return {"batch": size, "adapted": adapt, "adapt_us_per_frame": adapt_us,
            "localize_us_per_frame": localize_us,
            "compute_us_per_frame": adapt_us + localize_us}  # fmt: skip


def lower_bound_ratio(compute_us: float, floor_us: float) -> float:
    """The least server CPU per frame against the floor's: transport plus the compute."""
    if floor_us <= 0:
        raise ValueError("the floor's CPU per frame must be positive")
    return 1.0 + compute_us / floor_us

"""Prometheus metrics of the service layer (shared by REST and, later, gRPC).

One :class:`CollectorRegistry` per server instance, so that in-process test apps do not
collide; the HTTP layer adds its request metrics to the same registry.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Mapping
from typing import TYPE_CHECKING

from prometheus_client import CollectorRegistry, Counter, Histogram
from prometheus_client.core import GaugeMetricFamily
from prometheus_client.registry import Collector

if TYPE_CHECKING:
    from service.core.model_store import LoadedModel

LATENCY_BUCKETS = (0.0005, 0.001, 0.0025, 0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0, 2.5, 5.0)
JOB_BUCKETS = (1, 5, 15, 30, 60, 120, 300, 900, 1800, 3600, 4 * 3600, 12 * 3600)


class _StateCollector(Collector):
    """Gauges read at scrape time: loaded versions, their footprint, the queue depth."""

    def __init__(
        self,
        models: Callable[[], Mapping[str, LoadedModel]],
        queue_depth: Callable[[], int | None],
    ) -> None:
        self._models = models
        self._queue_depth = queue_depth

    def collect(self) -> Iterator[GaugeMetricFamily]:
        models = self._models()
        loaded = GaugeMetricFamily("gridplace_loaded_versions", "map versions held in memory")
        loaded.add_metric([], len(models))
        yield loaded
        version = GaugeMetricFamily(
            "gridplace_active_version", "version served per map", labels=["map"]
        )
        frames = GaugeMetricFamily(
            "gridplace_model_frames", "route length N of the served version", labels=["map"]
        )
        fp = GaugeMetricFamily(
            "gridplace_model_footprint_bytes",
            "storage footprint of the served version",
            labels=["map", "kind"],
        )
        for name, m in sorted(models.items()):
            version.add_metric([name], m.version)
            frames.add_metric([name], m.n_frames)
            footprint = m.info.footprint or {}
            for kind in ("paper_bytes", "actual_bytes"):
                if kind in footprint:
                    fp.add_metric([name, kind.removesuffix("_bytes")], float(footprint[kind]))
            fp.add_metric([name, "artifact"], float(m.info.artifact_bytes))
        yield version
        yield frames
        yield fp
        depth = self._queue_depth()
        if depth is not None:
            q = GaugeMetricFamily("gridplace_queue_depth", "training jobs waiting")
            q.add_metric([], depth)
            yield q


class ServiceMetrics:
    def __init__(self, registry: CollectorRegistry | None = None) -> None:
        self.registry = registry or CollectorRegistry()
        self.localize_seconds = Histogram(
            "gridplace_localize_seconds",
            "service-layer time of one localize call (decode + extract + encode)",
            ["map", "input"],
            buckets=LATENCY_BUCKETS,
            registry=self.registry,
        )
        self.queries = Counter(
            "gridplace_localize_queries", "descriptors localized", ["map", "input"],
            registry=self.registry,
        )  # fmt: skip
        self.batch_size = Histogram(
            "gridplace_localize_batch_size",
            "requests answered together by one micro-batch",
            buckets=(1, 2, 4, 8, 16, 32, 64, 128, 256, 1024),
            registry=self.registry,
        )
        self.job_seconds = Histogram(
            "gridplace_training_job_seconds",
            "wall time of finished training jobs, by outcome",
            ["state"],
            buckets=JOB_BUCKETS,
            registry=self.registry,
        )
        self.jobs_submitted = Counter(
            "gridplace_training_jobs_submitted", "training jobs accepted", registry=self.registry
        )
        self._seen_jobs: set[str] = set()

    def watch_state(
        self,
        models: Callable[[], Mapping[str, LoadedModel]],
        queue_depth: Callable[[], int | None],
    ) -> None:
        self.registry.register(_StateCollector(models, queue_depth))

    def observe_job(self, job_id: str, state: str, seconds: float | None) -> None:
        """Record a finished job's duration once, however often it is looked at."""
        if seconds is None or job_id in self._seen_jobs:
            return
        self._seen_jobs.add(job_id)
        self.job_seconds.labels(state=state).observe(seconds)

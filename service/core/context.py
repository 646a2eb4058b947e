"""Everything one server process holds, built once and shared by every transport.

REST (``service.api``) and gRPC (``service.grpc``) both receive the same
:class:`ServiceContext`: one registry handle, one training backend, one model store, one
service layer, one metrics registry.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from service.core.batching import MicroBatcher
from service.core.localization import LocalizationService
from service.core.metrics import ServiceMetrics
from service.core.model_store import ModelStore
from service.core.public_budget import PublicBudget
from service.core.stream_budget import StreamBudget
from service.core.vehicle_adapters import VehicleAdapters
from service.settings import Settings

if TYPE_CHECKING:
    from service.jobs import TrainingBackend
    from service.registry import Registry

log = logging.getLogger("gridplace.context")


@dataclass
class ServiceContext:
    settings: Settings
    registry: Registry
    backend: TrainingBackend
    store: ModelStore
    metrics: ServiceMetrics
    service: LocalizationService
    batcher: MicroBatcher | None = None  # None: localize inline (``batching`` off)
    vehicles: VehicleAdapters | None = None  # REST vehicles' appearance statistics
    streams: StreamBudget | None = None  # what open gRPC streams hold, server-wide
    public: PublicBudget | None = None  # public REST requests in flight, server-wide
    _blas: Any = None

    def __post_init__(self) -> None:
        s = self.settings
        if self.vehicles is None:
            self.vehicles = VehicleAdapters(s.adaptation(), s.max_rest_vehicles,
                                            s.rest_vehicle_state_mb * 2**20,
                                            s.condition_frames)  # fmt: skip
        if self.streams is None:
            self.streams = StreamBudget(s.max_streams, s.max_stream_vehicles,
                                        s.max_stream_state_mb * 2**20)  # fmt: skip
        if self.public is None:
            self.public = PublicBudget(s.max_public_requests, s.max_public_bodies_mb * 2**20)

    def start(self) -> None:
        """Start the hot-swap poller (its first pass loads every active version) and the
        micro-batcher, with the serving BLAS thread count."""
        if self.settings.serve_blas_threads and self._blas is None:
            from threadpoolctl import threadpool_limits

            self._blas = threadpool_limits(self.settings.serve_blas_threads, user_api="blas")
        self.store.start()
        if self.batcher is not None:
            self.batcher.start()

    def close(self) -> None:
        if self.batcher is not None:
            self.batcher.stop()
        self.store.stop()
        if self._blas is not None:
            self._blas.restore_original_limits()
            self._blas = None
        try:
            self.backend.close()
        except Exception:
            log.exception("closing the training backend failed")


def build_context(
    settings: Settings,
    registry: Registry | None = None,
    backend: TrainingBackend | None = None,
) -> ServiceContext:
    """The production wiring (registry under ``data_dir``, backend from settings); tests may
    pass their own registry or backend."""
    if registry is None:
        from service.registry import Registry

        settings.data_dir.mkdir(parents=True, exist_ok=True)
        registry = Registry(settings.data_dir)
    if backend is None:
        from service.jobs import make_backend

        backend = make_backend(settings, registry)
    metrics = ServiceMetrics()
    store = ModelStore(registry, settings.reload_interval_s)
    service = LocalizationService(settings, registry, backend, store, metrics)
    metrics.watch_state(store.snapshot, service.queue_depth)
    batcher = None
    if settings.batching:
        batcher = MicroBatcher(service, settings.batch_max_size, settings.batch_max_wait_ms / 1000)
    return ServiceContext(settings, registry, backend, store, metrics, service, batcher)

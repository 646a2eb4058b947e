"""The gRPC server of ``gridplace serve``: a companion of the REST app (same process, same
:class:`~service.core.context.ServiceContext`, its own port ``GRIDPLACE_GRPC_PORT``).

It runs a ``grpc.aio`` server on **its own thread and event loop**, not on uvicorn's: the
companion hook is synchronous (started and stopped from the app's lifespan), so a busy fleet
stream never stalls REST's event loop (or the reverse). The handlers' CPU work runs in two
bounded thread pools (``GRIDPLACE_GRPC_WORKERS`` threads in all, see
:class:`~service.grpc.servicer.Workers`), never on the loop, and messages larger than the
largest per-method cap are refused by gRPC itself, before anything is allocated for them. Both transports share one model store, so an activation is seen by both at once.

Also served: the standard health service (``grpc.health.v1.Health``; ``""`` and
``gridplace.v1.Localization`` are NOT_SERVING until every active version is loaded, the same
rule as REST ``/readyz``, and while shutting down) and server reflection.
"""

from __future__ import annotations

import asyncio
import logging
import threading

import grpc
from grpc_health.v1 import health_pb2, health_pb2_grpc
from grpc_health.v1.health import aio as health_aio
from grpc_reflection.v1alpha import reflection

from service.api.serving import port_in_use
from service.core.context import ServiceContext
from service.errors import UnavailableError
from service.grpc.gen import localization_pb2_grpc as pb_grpc
from service.grpc.servicer import SERVICE_NAME, LocalizationServicer, Workers
from service.settings import Settings

log = logging.getLogger("gridplace.grpc")

HEALTH_POLL_S = 0.25
GRACE_S = 5.0
_SERVING = health_pb2.HealthCheckResponse.SERVING
_NOT_SERVING = health_pb2.HealthCheckResponse.NOT_SERVING


class GrpcServer:
    """``start(context)`` binds and serves (raising if the port cannot be bound); ``stop()``
    drains calls for up to ``GRACE_S`` seconds."""

    name = "grpc"

    def __init__(self, settings: Settings) -> None:
        self.settings = settings
        self.address = f"{settings.host}:{settings.grpc_port}"
        self.port: int | None = None
        self._thread: threading.Thread | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._stopping: asyncio.Event | None = None
        self._started = threading.Event()
        self._error: BaseException | None = None

    # -- companion interface ---------------------------------------------------------
    def start(self, context: ServiceContext) -> None:
        self._thread = threading.Thread(target=self._run, args=(context,), name="gridplace-grpc",
                                        daemon=True)  # fmt: skip
        self._thread.start()
        if not self._started.wait(30):
            raise UnavailableError(f"the gRPC server did not start on {self.address}")
        if isinstance(self._error, UnavailableError):
            raise self._error
        if self._error is not None:
            raise UnavailableError(f"the gRPC server cannot serve on {self.address}: {self._error}")
        log.info("gRPC %s listening on %s:%s", SERVICE_NAME, self.settings.host, self.port)

    def stop(self) -> None:
        loop, stopping, thread = self._loop, self._stopping, self._thread
        if loop is not None and stopping is not None and not loop.is_closed():
            loop.call_soon_threadsafe(stopping.set)
        if thread is not None:
            thread.join(GRACE_S + 5)
        self._thread = None

    # -- the server thread --------------------------------------------------------------
    def _run(self, context: ServiceContext) -> None:
        self._loop = asyncio.new_event_loop()
        try:
            self._loop.run_until_complete(self._serve(context))
        except BaseException as exc:
            self._error = exc
            if self._started.is_set():
                log.exception("the gRPC server failed")
        finally:
            self._started.set()
            self._loop.close()

    async def _serve(self, context: ServiceContext) -> None:
        workers = Workers.from_settings(self.settings)
        try:
            await self._serve_with(context, workers)
        finally:
            workers.shutdown()

    async def _serve_with(self, context: ServiceContext, workers: Workers) -> None:
        server = grpc.aio.server(options=[
            ("grpc.max_receive_message_length", workers.max_message_bytes),
            ("grpc.max_send_message_length", self.settings.max_upload_mb * 1024 * 1024),
            ("grpc.so_reuseport", 0),  # a second server on this port fails instead of sharing it
            ("grpc.keepalive_permit_without_calls", 1),  # vehicles keep idle streams alive
            ("grpc.http2.min_ping_interval_without_data_ms", 10_000),
        ])  # fmt: skip
        pb_grpc.add_LocalizationServicer_to_server(LocalizationServicer(context, workers), server)
        health = health_aio.HealthServicer()
        health_pb2_grpc.add_HealthServicer_to_server(health, server)
        for service in ("", SERVICE_NAME):
            await health.set(service, _NOT_SERVING)
        reflection.enable_server_reflection(
            (SERVICE_NAME, health_pb2.DESCRIPTOR.services_by_name["Health"].full_name,
             reflection.SERVICE_NAME), server,
        )  # fmt: skip
        try:
            self.port = server.add_insecure_port(self.address)
        except RuntimeError as exc:
            raise port_in_use("gRPC", self.settings.host, self.settings.grpc_port,
                              "--grpc-port or GRIDPLACE_GRPC_PORT (0 = no gRPC)") from exc  # fmt: skip
        await server.start()
        self._stopping = asyncio.Event()
        self._started.set()
        watcher = asyncio.create_task(self._watch_readiness(context, health))
        try:
            await self._stopping.wait()
        finally:
            watcher.cancel()
            await health.enter_graceful_shutdown()  # NOT_SERVING while draining
            await server.stop(GRACE_S)

    async def _watch_readiness(self, context: ServiceContext, health: health_aio.HealthServicer) -> None:
        """Health follows the model store's readiness (the REST ``/readyz`` rule)."""
        current = None
        while True:
            status = _SERVING if context.store.ready() else _NOT_SERVING
            if status != current:
                for service in ("", SERVICE_NAME):
                    await health.set(service, status)
                current = status
            await asyncio.sleep(HEALTH_POLL_S)


def make_companion(settings: Settings) -> GrpcServer | None:
    """The gRPC server for ``gridplace serve`` (``None`` when ``grpc_port`` is 0)."""
    return GrpcServer(settings) if settings.grpc_port else None

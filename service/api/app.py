"""The FastAPI application factory of the gridplace model server."""

from __future__ import annotations

import logging
from collections.abc import AsyncIterator, Sequence
from contextlib import asynccontextmanager

from fastapi import FastAPI

from service.api import access_log, routes_admin, routes_health, routes_localize, routes_sequence
from service.api.auth import AdminGate
from service.api.companions import Companion
from service.api.errors import install_error_handlers
from service.api.inflight import PublicInflight
from service.api.limits import BodySizeLimit
from service.api.metrics import HttpMetrics
from service.core.context import ServiceContext, build_context
from service.settings import Settings, get_settings

log = logging.getLogger("gridplace.api")

DESCRIPTION = """Visual place recognition with sub-linear storage growth (Le & Milford 2018).

* **localize**: a descriptor, float32 bytes or an image → frame index on a map's route;
  `localize/sequence`: an ordered batch of frames as one drive (sequence filter).
* **admin** (bearer token): upload a route, follow its training job, activate / roll back /
  delete versions. Errors are JSON `{"error": code, "message": …}`.
"""


def create_app(
    settings: Settings | None = None,
    context: ServiceContext | None = None,
    companions: Sequence[Companion] = (),
) -> FastAPI:
    """The app; its lifespan starts the model store (and companions) and closes them."""
    settings = settings or get_settings()
    ctx = context or build_context(settings)

    @asynccontextmanager
    async def lifespan(_: FastAPI) -> AsyncIterator[None]:
        access_log.install(AdminGate.PREFIXES)  # after the server configured its loggers
        ctx.start()
        started: list[Companion] = []
        try:
            for companion in companions:
                companion.start(ctx)
                started.append(companion)
            yield
        finally:
            for companion in reversed(started):
                try:
                    companion.stop()
                except Exception:
                    log.exception("stopping %s failed", companion.name)
            ctx.close()

    app = FastAPI(
        title="gridplace",
        version="1",
        description=DESCRIPTION,
        lifespan=lifespan,
        docs_url="/docs",
        openapi_url="/openapi.json",
    )
    app.state.context = ctx
    install_error_handlers(app)
    app.include_router(routes_localize.router)
    app.include_router(routes_sequence.router)
    app.include_router(routes_admin.router)
    app.include_router(routes_health.router)
    assert ctx.public is not None
    # inside BodySizeLimit: a body over its own limit is a 413 before it takes any budget
    app.add_middleware(PublicInflight, budget=ctx.public, admin_prefixes=AdminGate.PREFIXES)
    app.add_middleware(BodySizeLimit, max_bytes=settings.max_upload_mb * 1024 * 1024,
                       public_max_bytes=settings.max_public_body_mb * 1024 * 1024,
                       admin_prefixes=AdminGate.PREFIXES)  # fmt: skip
    app.add_middleware(AdminGate, settings=settings)  # before any admin body is read
    app.add_middleware(HttpMetrics, registry=ctx.metrics.registry)  # outermost: counts 413s too
    return app

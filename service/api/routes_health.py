"""Liveness, readiness and Prometheus metrics."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter, Request, Response
from fastapi.responses import JSONResponse
from prometheus_client import CONTENT_TYPE_LATEST, generate_latest

from service.wire import Health, Readiness

router = APIRouter(tags=["health"])


@router.get("/healthz", summary="The process is alive", response_model=Health)
def healthz() -> Health:
    return Health(status="ok")


@router.get("/readyz", summary="Every map with an active version is loaded",
            response_model=Readiness,
            responses={503: {"model": Readiness, "description": "a map is not loaded (yet)"}})  # fmt: skip
def readyz(request: Request) -> JSONResponse:
    status: dict[str, Any] = request.app.state.context.store.status()
    return JSONResponse(status, status_code=200 if status["ready"] else 503)


@router.get("/metrics", summary="Prometheus metrics", response_class=Response,
            responses={200: {"content": {CONTENT_TYPE_LATEST: {"schema": {"type": "string"}}},
                             "description": "Prometheus text exposition format"}})  # fmt: skip
def metrics(request: Request) -> Response:
    ctx = request.app.state.context
    ctx.service.sync_job_metrics()
    registry = ctx.metrics.registry
    return Response(generate_latest(registry), media_type=CONTENT_TYPE_LATEST)

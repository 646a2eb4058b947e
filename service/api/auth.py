"""Bearer-token protection of the admin endpoints."""

from __future__ import annotations

import secrets
from typing import Annotated

from fastapi import Depends, Request
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer
from starlette.types import ASGIApp, Receive, Scope, Send

from service.api.errors import error_response
from service.errors import ForbiddenError, GridplaceError, UnauthorizedError
from service.settings import Settings


def check_admin(settings: Settings, authorization: str | None) -> None:
    """Allow the call or raise 401 (no/wrong token) / 403 (admin disabled)."""
    token = settings.admin_token.get_secret_value() if settings.admin_token else ""
    if not token:
        if settings.insecure_dev:
            return
        raise ForbiddenError(
            "the admin API is disabled: set GRIDPLACE_ADMIN_TOKEN (or GRIDPLACE_INSECURE_DEV=1 "
            "for local development)"
        )
    scheme, _, given = (authorization or "").partition(" ")
    if scheme.lower() != "bearer" or not given:
        raise UnauthorizedError("admin call without a bearer token (Authorization: Bearer <token>)")
    if not secrets.compare_digest(given.strip().encode(), token.encode()):
        raise UnauthorizedError("invalid admin token")


_bearer = HTTPBearer(auto_error=False, description="the server's GRIDPLACE_ADMIN_TOKEN")


def require_admin(
    request: Request,
    _: Annotated[HTTPAuthorizationCredentials | None, Depends(_bearer)] = None,
) -> None:
    """FastAPI dependency for the admin router (also documents bearer auth in /docs)."""
    check_admin(request.app.state.context.settings, request.headers.get("authorization"))


class AdminGate:
    """Refuse unauthenticated admin calls before their body is read.

    FastAPI parses a form (spooling an upload to disk) before it runs dependencies, so the
    router's ``require_admin`` alone would let anyone make the server swallow a large upload
    first. This ASGI layer answers 401/403 from the headers alone.
    """

    PREFIXES = ("/v1/maps", "/v1/jobs")

    def __init__(self, app: ASGIApp, settings: Settings) -> None:
        self.app = app
        self.settings = settings

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] == "http" and str(scope.get("path", "")).startswith(self.PREFIXES):
            authorization = None
            for key, value in scope.get("headers", ()):
                if key == b"authorization":
                    authorization = value.decode("latin-1")
            try:
                check_admin(self.settings, authorization)
            except GridplaceError as exc:
                await error_response(exc)(scope, receive, send)
                return
        await self.app(scope, receive, send)

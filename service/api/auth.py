"""Bearer-token protection of the admin endpoints."""

from __future__ import annotations

import secrets

from fastapi import Request

from service.errors import ForbiddenError, UnauthorizedError
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


def require_admin(request: Request) -> None:
    """FastAPI dependency for the admin router."""
    check_admin(request.app.state.context.settings, request.headers.get("authorization"))

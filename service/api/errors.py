"""One place where every failure becomes a JSON error body with the right status."""

from __future__ import annotations

import logging
from typing import Any

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from pydantic import ValidationError
from starlette.exceptions import HTTPException as StarletteHTTPException

from service.errors import CapacityError, GridplaceError, UnauthorizedError, error_class

log = logging.getLogger("gridplace.api")
RETRY_AFTER_S = 1  # a capacity refusal: what is held is given back as requests end
_METHODS = {"GET", "PUT", "POST", "DELETE", "OPTIONS", "HEAD", "PATCH", "TRACE"}


def error_response(exc: GridplaceError) -> JSONResponse:
    headers = None
    if isinstance(exc, UnauthorizedError):
        headers = {"WWW-Authenticate": "Bearer"}
    elif isinstance(exc, CapacityError):
        headers = {"Retry-After": str(RETRY_AFTER_S)}
    return JSONResponse(exc.to_dict(), status_code=exc.http_status, headers=headers)


def _validation_body(errors: list[Any]) -> dict[str, Any]:
    items = []
    for e in errors:
        loc = [str(p) for p in e.get("loc", ()) if p not in ("body", "query", "header", "form")]
        items.append({"field": ".".join(loc) or "body", "message": e.get("msg", ""),
                      "type": e.get("type", "")})  # fmt: skip
    message = "; ".join(f"{i['field']}: {i['message']}" for i in items) or "invalid request"
    code = error_class("validation_error", 422).code
    return {"error": code, "message": message, "details": {"errors": items}}


async def _gridplace(_: Request, exc: Exception) -> JSONResponse:
    assert isinstance(exc, GridplaceError)
    if isinstance(exc, CapacityError):  # expected under load: the caller is told to retry
        log.warning("%s: %s", exc.code, exc.message)
    elif exc.http_status >= 500:
        log.error("%s: %s", exc.code, exc.message)
    return error_response(exc)


async def _request_validation(_: Request, exc: Exception) -> JSONResponse:
    assert isinstance(exc, RequestValidationError)
    errors = list(exc.errors())
    # a body that is not JSON at all is a 400, a JSON body with wrong fields a 422
    status = 400 if any(e.get("type") == "json_invalid" for e in errors) else 422
    return JSONResponse(_validation_body(errors), status_code=status)


async def _pydantic_validation(_: Request, exc: Exception) -> JSONResponse:
    assert isinstance(exc, ValidationError)
    errors = exc.errors(include_url=False, include_context=False, include_input=False)
    status = 400 if any(e.get("type") == "json_invalid" for e in errors) else 422
    return JSONResponse(_validation_body(list(errors)), status_code=status)


def allowed_methods(request: Request) -> list[str]:
    """Every method the API documents at this path (Starlette's 405 names only the methods of
    the first route matching the path, e.g. GET but not DELETE)."""
    parts = request.url.path.strip("/").split("/")
    methods: set[str] = set()
    for template, operations in request.app.openapi().get("paths", {}).items():
        t = template.strip("/").split("/")
        if len(t) == len(parts) and all(
            a == b or (a.startswith("{") and a.endswith("}")) for a, b in zip(t, parts, strict=True)
        ):
            methods |= {m.upper() for m in operations if m.upper() in _METHODS}
    if "GET" in methods:
        methods.add("HEAD")
    return sorted(methods)


async def _http(request: Request, exc: Exception) -> JSONResponse:
    assert isinstance(exc, StarletteHTTPException)
    if isinstance(exc.__cause__, GridplaceError):  # e.g. 413 raised while FastAPI parsed a form
        return error_response(exc.__cause__)
    headers = dict(exc.headers or {})
    if exc.status_code == 405:
        headers["Allow"] = ", ".join(allowed_methods(request))
    cls = error_class(None, exc.status_code)
    code = cls.code if cls.http_status == exc.status_code else "http_error"
    body = {"error": code, "message": str(exc.detail)}
    return JSONResponse(body, status_code=exc.status_code, headers=headers or None)


async def _unexpected(_: Request, exc: Exception) -> JSONResponse:
    log.exception("unhandled error", exc_info=exc)
    return JSONResponse({"error": "internal_error", "message": "internal server error"},
                        status_code=500)  # fmt: skip


def install_error_handlers(app: FastAPI) -> None:
    app.add_exception_handler(GridplaceError, _gridplace)
    app.add_exception_handler(RequestValidationError, _request_validation)
    app.add_exception_handler(ValidationError, _pydantic_validation)
    app.add_exception_handler(StarletteHTTPException, _http)
    app.add_exception_handler(Exception, _unexpected)

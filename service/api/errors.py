"""One place where every failure becomes a JSON error body with the right status."""

from __future__ import annotations

import logging
from typing import Any

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from pydantic import ValidationError
from starlette.exceptions import HTTPException as StarletteHTTPException

from service.errors import GridplaceError, UnauthorizedError

log = logging.getLogger("gridplace.api")

_HTTP_CODES = {400: "bad_request", 404: "not_found", 405: "method_not_allowed",
               413: "payload_too_large", 415: "unsupported_media_type"}  # fmt: skip


def error_response(exc: GridplaceError) -> JSONResponse:
    headers = {"WWW-Authenticate": "Bearer"} if isinstance(exc, UnauthorizedError) else None
    return JSONResponse(exc.to_dict(), status_code=exc.http_status, headers=headers)


def _validation_body(errors: list[Any]) -> dict[str, Any]:
    items = []
    for e in errors:
        loc = [str(p) for p in e.get("loc", ()) if p not in ("body", "query", "header", "form")]
        items.append({"field": ".".join(loc) or "body", "message": e.get("msg", ""),
                      "type": e.get("type", "")})  # fmt: skip
    message = "; ".join(f"{i['field']}: {i['message']}" for i in items) or "invalid request"
    return {"error": "validation_error", "message": message, "details": {"errors": items}}


async def _gridplace(_: Request, exc: Exception) -> JSONResponse:
    assert isinstance(exc, GridplaceError)
    if exc.http_status >= 500:
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


async def _http(_: Request, exc: Exception) -> JSONResponse:
    assert isinstance(exc, StarletteHTTPException)
    if isinstance(exc.__cause__, GridplaceError):  # e.g. 413 raised while FastAPI parsed a form
        return error_response(exc.__cause__)
    body = {"error": _HTTP_CODES.get(exc.status_code, "http_error"), "message": str(exc.detail)}
    return JSONResponse(body, status_code=exc.status_code, headers=exc.headers)


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

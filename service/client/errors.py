"""Error answers of a gridplace server, raised as the classes of :mod:`service.errors`.

The server answers every failure with ``{"error": code, "message": ..., "details": ...}``.
:func:`error_from_response` turns that body back into the matching class of the one error
hierarchy (a ``dimension_mismatch`` answer raises :class:`DimensionMismatchError`, a 404
:class:`NotFoundError`…), so callers catch the same classes in-process and over HTTP. A few
failures only a client sees get their own subclasses here.
"""

from __future__ import annotations

from typing import Any

import httpx

from service.errors import (
    ConflictError,
    ForbiddenError,
    GridplaceError,
    InvalidInputError,
    NotFoundError,
    PayloadTooLargeError,
    UnauthorizedError,
    UnavailableError,
)


class RequestValidationError(InvalidInputError):
    """The server's schema validation refused the request (422)."""

    code = "validation_error"
    http_status = 422


class ServerUnreachableError(UnavailableError):
    """No answer at all: connection refused, DNS failure, timeout, broken connection."""

    code = "server_unreachable"


class UnexpectedResponseError(GridplaceError):
    """The server answered something that is not a gridplace response (a proxy page…)."""

    code = "unexpected_response"
    http_status = 502
    grpc_status = "UNKNOWN"


class JobFailedError(GridplaceError):
    """A training job ended in ``failed`` (raised by callers that asked for success)."""

    code = "job_failed"
    http_status = 500
    grpc_status = "ABORTED"


class JobTimeoutError(GridplaceError, TimeoutError):
    """A job did not finish within the time the caller was willing to wait."""

    code = "job_timeout"
    http_status = 504
    grpc_status = "DEADLINE_EXCEEDED"


# Fallback by HTTP status when the code is not one of ours (e.g. a plain proxy 503).
_BY_STATUS: dict[int, type[GridplaceError]] = {
    400: InvalidInputError,
    401: UnauthorizedError,
    403: ForbiddenError,
    404: NotFoundError,
    405: InvalidInputError,
    409: ConflictError,
    413: PayloadTooLargeError,
    415: InvalidInputError,
    422: RequestValidationError,
    503: UnavailableError,
}


def _all_subclasses(cls: type[GridplaceError]) -> list[type[GridplaceError]]:
    out: list[type[GridplaceError]] = []
    for sub in cls.__subclasses__():
        out.append(sub)
        out.extend(_all_subclasses(sub))
    return out


def error_class(code: str | None, status: int) -> type[GridplaceError]:
    """The class for a server error ``code`` (same code and HTTP status), else by ``status``."""
    known: list[type[GridplaceError]] = [GridplaceError, *_all_subclasses(GridplaceError)]
    candidates = [c for c in known if c.code == code]
    for cls in candidates:
        if cls.http_status == status:
            return cls
    if candidates:
        return candidates[0]
    if status in _BY_STATUS:
        return _BY_STATUS[status]
    if 400 <= status < 500:
        return InvalidInputError
    return GridplaceError


def error_from_response(response: httpx.Response) -> GridplaceError:
    """The exception an error response stands for (the server's message, code in details)."""
    status = response.status_code
    body: Any
    try:
        body = response.json()
    except ValueError:
        body = None
    if isinstance(body, dict) and isinstance(body.get("error"), str):
        code: str = body["error"]
        message = str(body.get("message") or code)
        raw = body.get("details")
        details: dict[str, Any] = dict(raw) if isinstance(raw, dict) else {}
        cls = error_class(code, status)
        exc = cls(message, **details)
        if exc.code != code:  # a code this client does not know: keep the server's word
            exc.details.setdefault("server_code", code)
        exc.details.setdefault("http_status", status)
        return exc
    text = response.text.strip().replace("\n", " ")[:200]
    cls = _BY_STATUS.get(status, UnexpectedResponseError if status < 500 else GridplaceError)
    try:
        where = f"{response.request.method} {response.request.url}"
    except RuntimeError:  # a response built by hand has no request
        where = "the server"
    return cls(f"HTTP {status} from {where}: {text or 'empty body'}", http_status=status)


def transport_error(exc: httpx.TransportError, base_url: str) -> ServerUnreachableError:
    """A clear message for a request that got no answer."""
    if isinstance(exc, httpx.TimeoutException):
        what = f"timed out ({type(exc).__name__})"
    elif isinstance(exc, httpx.ConnectError):
        what = "connection failed"
    else:
        what = type(exc).__name__
    detail = str(exc) or what
    return ServerUnreachableError(
        f"cannot reach the gridplace server at {base_url}: {what}: {detail} "
        "(is `gridplace serve` running? set --url or GRIDPLACE_URL)",
        url=base_url,
    )

"""Error answers of a gridplace server, raised as the classes of :mod:`service.errors`.

The server answers every failure with an :class:`~service.wire.ErrorBody`
(``{"error": code, "message": ..., "details": ...}``); :func:`error_from_response` turns it
back into the class of the one error hierarchy with that code (a ``dimension_mismatch``
answer raises :class:`DimensionMismatchError`, a 404 :class:`NotFoundError`…) through
:func:`service.errors.error_class`, so callers catch the same classes in-process and over
HTTP. Failures only a client sees (no answer, a job that failed or timed out) get their own
subclasses here.
"""

from __future__ import annotations

from typing import Any

import httpx
from pydantic import ValidationError

from service.errors import GridplaceError, RequestValidationError, UnavailableError, error_class
from service.wire import ErrorBody

__all__ = [
    "JobFailedError",
    "JobTimeoutError",
    "RequestValidationError",
    "ServerUnreachableError",
    "UnexpectedResponseError",
    "error_from_response",
    "transport_error",
]


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


def _error_body(response: httpx.Response) -> ErrorBody | None:
    try:
        return ErrorBody.model_validate_json(response.content)
    except ValidationError:
        return None


def error_from_response(response: httpx.Response) -> GridplaceError:
    """The exception an error response stands for (the server's message, code in details)."""
    status = response.status_code
    body = _error_body(response)
    if body is not None:
        details: dict[str, Any] = dict(body.details or {})
        exc = error_class(body.error, status)(body.message or body.error, **details)
        if exc.code != body.error:  # a code this client does not know: keep the server's word
            exc.details.setdefault("server_code", body.error)
        exc.details.setdefault("http_status", status)
        return exc
    text = response.text.strip().replace("\n", " ")[:200]
    cls = error_class(None, status)
    if cls.http_status != status:  # no class of the hierarchy has this status
        cls = UnexpectedResponseError if status < 500 else GridplaceError
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

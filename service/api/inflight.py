"""Public REST requests lease from the server-wide budget while in flight, as ASGI middleware.

Every public request that may carry a body (any method but GET and HEAD, on any path but the
admin ones, which are authenticated and keep their own ``GRIDPLACE_MAX_UPLOAD_MB``) takes a
:class:`~service.core.public_budget.PublicLease` when its headers arrive and gives it back
when its answer has been sent: its declared ``Content-Length`` is reserved before the body
is read, a chunked body's bytes as they arrive. A request that does not fit is answered 503
``capacity_exhausted`` with ``Retry-After`` before its body is read (or, for a chunked body,
when the bytes that would not fit arrive), naming the setting. This runs inside
:class:`~service.api.limits.BodySizeLimit`, so a body over the per-request limit is a 413
first.
"""

from __future__ import annotations

from starlette.types import ASGIApp, Message, Receive, Scope, Send

from service.api.errors import error_response
from service.core.public_budget import PublicBudget
from service.errors import CapacityError

BODILESS = frozenset({"GET", "HEAD"})  # no public route reads a body: health probes stay free


class PublicInflight:
    def __init__(self, app: ASGIApp, budget: PublicBudget, admin_prefixes: tuple[str, ...]) -> None:
        self.app = app
        self.budget = budget
        self.admin_prefixes = admin_prefixes

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if (scope["type"] != "http" or scope.get("method") in BODILESS
                or str(scope.get("path", "")).startswith(self.admin_prefixes)):  # fmt: skip
            await self.app(scope, receive, send)
            return
        declared = 0
        for key, value in scope.get("headers", ()):
            if key == b"content-length":
                try:
                    declared = max(int(value), 0)
                except ValueError:
                    declared = 0
        try:
            lease = self.budget.open(declared)
        except CapacityError as exc:
            await error_response(exc)(scope, receive, send)
            return

        async def counted() -> Message:
            message = await receive()
            if message["type"] == "http.request":
                lease.receive(len(message.get("body", b"")))
            return message

        try:
            await self.app(scope, counted, send)
        finally:
            lease.close()

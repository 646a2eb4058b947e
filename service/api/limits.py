"""Request-body size limits (413 before and while reading), as plain ASGI middleware.

Two limits: admin paths (already authenticated by :class:`~service.api.auth.AdminGate`, which
runs first) may send uploads up to ``GRIDPLACE_MAX_UPLOAD_MB``; every other path is public and
gets ``GRIDPLACE_MAX_PUBLIC_BODY_MB``, so an anonymous caller cannot make the server read (and
parse) a body sized for a route upload.
"""

from __future__ import annotations

from starlette.types import ASGIApp, Message, Receive, Scope, Send

from service.api.errors import error_response
from service.errors import PayloadTooLargeError


def _too_large(limit: int, setting: str, got: int | None = None) -> PayloadTooLargeError:
    what = f"{got} bytes" if got is not None else "more"
    return PayloadTooLargeError(
        f"request body of {what} exceeds the {limit // (1024 * 1024)} MiB limit ({setting})",
        limit_bytes=limit,
    )  # fmt: skip


class BodySizeLimit:
    def __init__(self, app: ASGIApp, max_bytes: int, public_max_bytes: int,
                 admin_prefixes: tuple[str, ...]) -> None:  # fmt: skip
        self.app = app
        self.max_bytes = max_bytes
        self.public_max_bytes = public_max_bytes
        self.admin_prefixes = admin_prefixes

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        if str(scope.get("path", "")).startswith(self.admin_prefixes):
            limit, setting = self.max_bytes, "GRIDPLACE_MAX_UPLOAD_MB"
        else:
            limit, setting = self.public_max_bytes, "GRIDPLACE_MAX_PUBLIC_BODY_MB"
        for key, value in scope.get("headers", ()):
            if key == b"content-length":
                try:
                    declared = int(value)
                except ValueError:
                    declared = 0
                if declared > limit:
                    await error_response(_too_large(limit, setting, declared))(scope, receive, send)
                    return
        seen = 0

        async def limited() -> Message:
            nonlocal seen
            message = await receive()
            if message["type"] == "http.request":
                seen += len(message.get("body", b""))
                if seen > limit:
                    raise _too_large(limit, setting)
            return message

        await self.app(scope, limited, send)

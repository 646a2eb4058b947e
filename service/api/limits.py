"""Request-body size limit (413 before and while reading), as plain ASGI middleware."""

from __future__ import annotations

from starlette.types import ASGIApp, Message, Receive, Scope, Send

from service.api.errors import error_response
from service.errors import PayloadTooLargeError


def _too_large(limit: int, got: int | None = None) -> PayloadTooLargeError:
    what = f"{got} bytes" if got is not None else "more"
    return PayloadTooLargeError(
        f"request body of {what} exceeds the {limit // (1024 * 1024)} MiB limit "
        "(GRIDPLACE_MAX_UPLOAD_MB)", limit_bytes=limit,
    )  # fmt: skip


class BodySizeLimit:
    def __init__(self, app: ASGIApp, max_bytes: int) -> None:
        self.app = app
        self.max_bytes = max_bytes

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        for key, value in scope.get("headers", ()):
            if key == b"content-length":
                try:
                    declared = int(value)
                except ValueError:
                    declared = 0
                if declared > self.max_bytes:
                    await error_response(_too_large(self.max_bytes, declared))(scope, receive, send)
                    return
        seen = 0

        async def limited() -> Message:
            nonlocal seen
            message = await receive()
            if message["type"] == "http.request":
                seen += len(message.get("body", b""))
                if seen > self.max_bytes:
                    raise _too_large(self.max_bytes)
            return message

        await self.app(scope, limited, send)

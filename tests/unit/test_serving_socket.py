"""The REST listener that ``gridplace serve`` binds itself must behave like uvicorn's own."""

from __future__ import annotations

import asyncio
import socket

from service.api.serving import bind_listener


def test_accepted_connections_disable_nagle() -> None:
    """Small answers must not wait for Nagle's algorithm and the client's delayed ACK (a
    ~40 ms stall per request): asyncio sets TCP_NODELAY only on sockets whose protocol
    says TCP, so the listener must be created with it."""
    listener = bind_listener("127.0.0.1", 0, "REST", "--port")
    assert listener.proto == socket.IPPROTO_TCP

    async def main() -> int:
        seen: asyncio.Future[int] = asyncio.get_running_loop().create_future()

        async def handle(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
            sock = writer.get_extra_info("socket")
            seen.set_result(sock.getsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY))
            writer.close()

        server = await asyncio.start_server(handle, sock=listener)
        async with server:
            port = listener.getsockname()[1]
            _, writer = await asyncio.open_connection("127.0.0.1", port)
            value = await asyncio.wait_for(seen, 10)
            writer.close()
            return value

    assert asyncio.run(main()) != 0

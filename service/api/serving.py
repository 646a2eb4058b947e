"""Running ``gridplace serve`` as a process: ports first, a quiet end on SIGINT and SIGTERM.

* The REST port is bound (and listening, without SO_REUSEPORT) before anything else starts, and
  the gRPC port is checked next: a port another process holds ends the command with one clear
  line and exit code 2 before the model store, the training backend or the gRPC server start,
  so a second server never answers a single request (the gRPC server binds without port
  reuse too, so even a race for the port fails instead of sharing it).
* SIGINT (Ctrl-C, which a terminal sends to the whole process group) and SIGTERM start the
  graceful shutdown: stop accepting, drain requests, stop gRPC, mark unfinished training jobs
  failed with the reason, stop the training pool; then the process exits with code 0.
"""

from __future__ import annotations

import errno
import logging
import signal
import socket
from types import FrameType

import uvicorn

from service.errors import UnavailableError
from service.settings import Settings

log = logging.getLogger("gridplace.serve")

SHUTDOWN_SIGNALS = (signal.SIGINT, signal.SIGTERM)
GRACEFUL_SHUTDOWN_S = 10


def port_in_use(what: str, host: str, port: int, how_to_change: str) -> UnavailableError:
    return UnavailableError(
        f"{what} port {host}:{port} is already in use (another gridplace serve?); "
        f"choose another with {how_to_change}", host=host, port=port,
    )  # fmt: skip


def _address(host: str, port: int) -> tuple[socket.AddressFamily, int, tuple[object, ...]]:
    try:
        family, _, proto, _, address = socket.getaddrinfo(
            host, port, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE
        )[0]
    except socket.gaierror as exc:
        raise UnavailableError(f"cannot bind to {host!r}: {exc}", host=host) from exc
    return family, proto or socket.IPPROTO_TCP, address


def bind_listener(host: str, port: int, what: str, how_to_change: str) -> socket.socket:
    """A listening TCP socket on ``host:port`` (SO_REUSEADDR only: a port in TIME_WAIT can be
    reused, one that another process listens on cannot).

    The socket is created with its protocol named (IPPROTO_TCP): asyncio sets TCP_NODELAY
    only on accepted sockets whose ``proto`` says TCP, and without it every small answer
    waits ~40 ms for Nagle's algorithm and the client's delayed ACK."""
    family, proto, address = _address(host, port)
    sock = socket.socket(family, socket.SOCK_STREAM, proto)
    try:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        sock.bind(address)
        sock.listen(2048)
    except OSError as exc:
        sock.close()
        if exc.errno == errno.EADDRINUSE:
            raise port_in_use(what, host, port, how_to_change) from exc
        raise UnavailableError(f"cannot listen on {what} {host}:{port}: {exc}") from exc
    return sock


def check_port_free(host: str, port: int, what: str, how_to_change: str) -> None:
    """Fail now if ``host:port`` cannot be bound (the server that needs it binds it later)."""
    bind_listener(host, port, what, how_to_change).close()


class ShutdownSignals:
    """Records SIGINT/SIGTERM instead of raising. uvicorn installs its own handlers while it
    runs and, once its graceful shutdown is over, restores these and re-sends the signal it
    got: here that is a clean exit, not a ``KeyboardInterrupt`` or a death by SIGTERM."""

    def __init__(self) -> None:
        self.received: list[int] = []

    def install(self) -> ShutdownSignals:
        for sig in SHUTDOWN_SIGNALS:
            signal.signal(sig, self._record)
        return self

    def _record(self, signum: int, frame: FrameType | None) -> None:
        self.received.append(signum)

    def names(self) -> str:
        return ", ".join(dict.fromkeys(signal.Signals(s).name for s in self.received))


class _Server(uvicorn.Server):
    """uvicorn's server, announcing where REST answers once the app has started (uvicorn says
    nothing when it is handed an already bound socket)."""

    async def startup(self, sockets: list[socket.socket] | None = None) -> None:
        await super().startup(sockets=sockets)
        if self.started:
            for sock in sockets or ():
                host, port = sock.getsockname()[:2]
                log.info("REST serving on http://%s:%s", host, port)


def serve_forever(settings: Settings) -> None:
    """Bind, start, serve until SIGINT/SIGTERM, shut down; return normally (exit 0)."""
    from service.api.app import create_app
    from service.api.companions import discover_companions

    signals = ShutdownSignals().install()
    rest = bind_listener(settings.host, settings.port, "REST", "--port or GRIDPLACE_PORT")
    try:
        if settings.grpc_port:
            check_port_free(settings.host, settings.grpc_port, "gRPC",
                            "--grpc-port or GRIDPLACE_GRPC_PORT (0 = no gRPC)")  # fmt: skip
        app = create_app(settings, companions=discover_companions(settings))
        config = uvicorn.Config(app, log_level=settings.log_level.lower(),
                                timeout_graceful_shutdown=GRACEFUL_SHUTDOWN_S)  # fmt: skip
        if signals.received:
            return  # stopped while starting: nothing was served
        _Server(config).run(sockets=[rest])
    finally:
        rest.close()
    if signals.received:
        log.info("gridplace serve stopped (%s)", signals.names())

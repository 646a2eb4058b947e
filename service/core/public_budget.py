"""Server-wide bounds on public requests in flight: how many, and the bytes of their bodies.

Public requests are REST calls on every path but the admin ones (GET and HEAD aside: no
public route reads their body) and gRPC unary ``Localize`` calls (a stream leases from
:mod:`service.core.stream_budget` instead).

Each public request's body is capped (``GRIDPLACE_MAX_PUBLIC_BODY_MB``) and its work too
(``GRIDPLACE_MAX_REQUEST_WORK``), but anonymous callers choose how many they send at once, and
a body being received slowly holds its bytes (and, once parsed, its parse) for as long as the
caller likes. So public requests lease from one budget while they are in flight, from their
headers to the end of their answer: ``GRIDPLACE_MAX_PUBLIC_REQUESTS`` requests and
``GRIDPLACE_MAX_PUBLIC_BODIES_MB`` of body bytes, every caller together. A request with a
``Content-Length`` reserves it before its first byte is read; a chunked body reserves what
arrives as it arrives. Beyond either limit the request is refused with
:class:`~service.errors.CapacityError` (HTTP 503 with ``Retry-After``), naming the setting;
requests already in flight go on.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass

from service.errors import CapacityError

MIB = 2**20


@dataclass(frozen=True)
class PublicUse:
    requests: int
    nbytes: int


class PublicBudget:
    """The server-wide counters (thread-safe: REST's loop and gRPC's may share them)."""

    def __init__(self, max_requests: int, max_bytes: int) -> None:
        self.max_requests = max_requests
        self.max_bytes = max_bytes
        self._lock = threading.Lock()
        self._requests = self._bytes = 0

    def use(self) -> PublicUse:
        with self._lock:
            return PublicUse(self._requests, self._bytes)

    def open(self, nbytes: int = 0) -> PublicLease:
        """A lease for one more request whose body is ``nbytes`` (as declared; 0 when unknown),
        or :class:`CapacityError` when it does not fit."""
        with self._lock:
            if self._requests >= self.max_requests:
                raise CapacityError(
                    f"the server has {self._requests} public requests in flight, its limit "
                    f"(GRIDPLACE_MAX_PUBLIC_REQUESTS={self.max_requests}); retry later",
                    limit=self.max_requests, setting="GRIDPLACE_MAX_PUBLIC_REQUESTS",
                )  # fmt: skip
            self._check_bytes(nbytes)
            self._requests += 1
            self._bytes += nbytes
        return PublicLease(self, nbytes)

    def _check_bytes(self, more: int) -> None:
        if self._bytes + more > self.max_bytes:
            raise CapacityError(
                f"public requests in flight hold {self._bytes} bytes of body; {more} more for "
                f"this one exceed the server's limit (GRIDPLACE_MAX_PUBLIC_BODIES_MB="
                f"{self.max_bytes / MIB:g}); retry later",
                limit=self.max_bytes, setting="GRIDPLACE_MAX_PUBLIC_BODIES_MB",
            )  # fmt: skip

    def _grow(self, more: int) -> None:
        with self._lock:
            self._check_bytes(more)
            self._bytes += more

    def _release(self, nbytes: int) -> None:
        with self._lock:
            self._requests -= 1
            self._bytes -= nbytes


class PublicLease:
    """One request's share: the bytes reserved for its body (grown as an undeclared body
    arrives), given back by :meth:`close` (idempotent)."""

    def __init__(self, budget: PublicBudget, reserved: int) -> None:
        self._budget = budget
        self.reserved = reserved
        self.received = 0
        self.closed = False

    def receive(self, nbytes: int) -> None:
        """``nbytes`` more of the body arrived (:class:`CapacityError` when they exceed what
        is reserved and the budget cannot hold them)."""
        received = self.received + nbytes
        if received > self.reserved and not self.closed:
            self._budget._grow(received - self.reserved)
            self.reserved = received
        self.received = received

    def close(self) -> None:
        if not self.closed:
            self.closed = True
            self._budget._release(self.reserved)

    def __enter__(self) -> PublicLease:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

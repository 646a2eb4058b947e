"""Server-wide bounds on what open streams hold: streams, vehicle states and their bytes.

Each stream caps its own vehicles (:mod:`service.core.streams`), but streams are opened by
anonymous callers, so their number and what they hold together are bounded here too, by
settings: ``GRIDPLACE_MAX_STREAMS`` open streams, ``GRIDPLACE_MAX_STREAM_VEHICLES`` vehicle
states (a vehicle's sequence filter and its appearance statistics count one each) and
``GRIDPLACE_MAX_STREAM_STATE_MB`` of them. A stream takes a :class:`StreamLease` when it opens
(refused with :class:`~service.errors.CapacityError`, gRPC ``RESOURCE_EXHAUSTED``, when every
stream is taken); each new vehicle state is reserved from it (a frame that would need more is
refused the same way, the stream and its other vehicles going on), and the lease gives back
all it holds when the stream closes. What a closed stream held is then returned to the
operating system (glibc keeps freed blocks of a few hundred kB in its arenas otherwise: six
closed streams of filtered vehicles kept 3 GB of RSS).
"""

from __future__ import annotations

import ctypes
import ctypes.util
import functools
import logging
import threading
from collections.abc import Callable
from dataclasses import dataclass

from service.errors import CapacityError

log = logging.getLogger("gridplace.streams")

#: a closed stream that held at least this much returns freed memory to the OS
TRIM_AFTER_BYTES = 8 * 1024 * 1024


@dataclass(frozen=True)
class BudgetUse:
    streams: int
    states: int
    nbytes: int


class StreamBudget:
    """The server-wide counters (thread-safe)."""

    def __init__(self, max_streams: int, max_states: int, max_bytes: int) -> None:
        self.max_streams = max_streams
        self.max_states = max_states
        self.max_bytes = max_bytes
        self._lock = threading.Lock()
        self._streams = self._states = self._bytes = 0

    def use(self) -> BudgetUse:
        with self._lock:
            return BudgetUse(self._streams, self._states, self._bytes)

    def open(self) -> StreamLease:
        """A lease for a new stream, or :class:`CapacityError` when all are taken."""
        with self._lock:
            if self._streams >= self.max_streams:
                raise CapacityError(
                    f"the server has {self._streams} streams open, its limit "
                    f"(GRIDPLACE_MAX_STREAMS={self.max_streams}); retry later", limit=self.max_streams,
                )  # fmt: skip
            self._streams += 1
        return StreamLease(self)

    def _reserve(self, nbytes: int) -> None:
        with self._lock:
            if self._states >= self.max_states:
                raise CapacityError(
                    f"open streams hold {self._states} vehicle states, the server's limit "
                    f"(GRIDPLACE_MAX_STREAM_VEHICLES={self.max_states}); this frame needs one "
                    "more: retry later or send it without the sequence filter and adaptation",
                    limit=self.max_states,
                )  # fmt: skip
            if self._bytes + nbytes > self.max_bytes:
                mib = self.max_bytes / 2**20
                raise CapacityError(
                    f"open streams hold {self._bytes} bytes of vehicle state; {nbytes} more for "
                    f"this frame exceed the server's limit (GRIDPLACE_MAX_STREAM_STATE_MB="
                    f"{mib:g}): retry later or send it without the sequence filter and adaptation",
                    limit=self.max_bytes,
                )  # fmt: skip
            self._states += 1
            self._bytes += nbytes

    def _release(self, states: int, nbytes: int, stream: bool) -> None:
        with self._lock:
            self._states -= states
            self._bytes -= nbytes
            self._streams -= int(stream)


class StreamLease:
    """One open stream's share of the budget (not thread-safe: one stream, one caller)."""

    def __init__(self, budget: StreamBudget) -> None:
        self._budget = budget
        self.states = 0
        self.nbytes = 0
        self.closed = False
        self._held = 0  # the most this lease held at once

    def reserve(self, nbytes: int) -> None:
        """One more vehicle state of ``nbytes`` (:class:`CapacityError` when it does not fit)."""
        if self.closed:
            raise CapacityError("the stream is closed")
        self._budget._reserve(nbytes)
        self.states += 1
        self.nbytes += nbytes
        self._held = max(self._held, self.nbytes)

    def release(self, nbytes: int) -> None:
        """One vehicle state of ``nbytes`` dropped."""
        if self.closed:
            return
        self._budget._release(1, nbytes, stream=False)
        self.states -= 1
        self.nbytes -= nbytes

    def close(self) -> None:
        """Give everything back (idempotent); the caller has dropped its states first."""
        if self.closed:
            return
        self.closed = True
        self._budget._release(self.states, self.nbytes, stream=True)
        self.states = self.nbytes = 0
        if self._held >= TRIM_AFTER_BYTES:
            release_free_memory()


@functools.cache
def _malloc_trim() -> Callable[[int], int] | None:
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c"))
    except OSError:
        return None
    return getattr(libc, "malloc_trim", None)  # glibc only


def release_free_memory() -> bool:
    """Return the C heap's free memory to the operating system (glibc ``malloc_trim``; a
    no-op elsewhere). True when something was released."""
    trim = _malloc_trim()
    return bool(trim(0)) if trim is not None else False

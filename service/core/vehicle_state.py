"""Per-vehicle state that belongs to one map version, least recently used first forgotten.

A vehicle's sequence filter and its appearance adapter are both built from one served model
version: when the version (or the map) behind a key changes, or the caller asks for a
restart, the state starts afresh, so two models' evidence is never mixed — except that a
version built from the state's own by appending traversals (:func:`lineage`), which indexes
the same places, takes the state over when the state says it fits (``carry``: the filter
when the number of places is unchanged, the adapter when the route statistics are): a
vehicle keeps its place across a version swap of its route; :attr:`VehicleState.change`
says what the last :meth:`current` did. Entries beyond ``max_items``, or beyond
``max_bytes`` of state together, are dropped least recently used first (the newest one
always stays). Each entry counts its value's bytes and
``ENTRY_OVERHEAD_BYTES`` for the entry itself (its key of up to 128 characters, the mapping's
slot; measured with tracemalloc). With a ``lease`` (:mod:`service.core.stream_budget`) every
entry is also reserved from a server-wide budget before it is kept, and released when it is
dropped: a new entry the budget cannot hold is refused (``CapacityError``), the store's other
entries untouched. Not thread-safe: callers serialise access.
"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Callable, Hashable, Iterator
from dataclasses import dataclass
from typing import TYPE_CHECKING, Generic, TypeVar

from service.core.model_store import LoadedModel

if TYPE_CHECKING:
    from service.core.stream_budget import StreamLease

K = TypeVar("K", bound=Hashable)
V = TypeVar("V")

ENTRY_OVERHEAD_BYTES = 512


@dataclass
class _Entry(Generic[V]):
    map: str
    version: int
    value: V
    nbytes: int


def lineage(loaded: LoadedModel) -> frozenset[int]:
    """A served version and every version it was built from by appending traversals (the
    ``version`` and ``appended_to`` of its ``extra.traversals``)."""
    versions = {int(loaded.version)}
    extra = getattr(getattr(loaded, "info", None), "extra", None) or {}
    for t in extra.get("traversals") or []:
        for key in ("version", "appended_to"):
            if isinstance(t.get(key), int):
                versions.add(int(t[key]))
    return frozenset(versions)


class VehicleState(Generic[K, V]):
    """``key`` → state of ``loaded``'s version (:meth:`current`), bounded in count and bytes."""

    def __init__(self, max_items: int, max_bytes: int, nbytes: Callable[[V], int],
                 lease: StreamLease | None = None) -> None:  # fmt: skip
        self.max_items = max_items
        self.max_bytes = max_bytes
        self._size = nbytes
        self._lease = lease
        self._entries: OrderedDict[K, _Entry[V]] = OrderedDict()
        self._bytes = 0
        #: what the last :meth:`current` did: "" (the key's state as it was, or a new key's),
        #: "carried" (into another version of the same places) or "restarted"
        self.change = ""

    def __len__(self) -> int:
        return len(self._entries)

    def __iter__(self) -> Iterator[K]:
        return iter(self._entries)

    @property
    def nbytes(self) -> int:
        """Bytes the states hold together (entries included)."""
        return self._bytes

    def current(self, key: K, loaded: LoadedModel, start: Callable[[], V],
                restart: bool = False, carry: Callable[[V], bool] | None = None) -> V:  # fmt: skip
        """``key``'s state for ``loaded`` (``start()`` makes a new one when there is none, it
        belongs to another map or version, or ``restart``); a state of a version ``loaded``
        was appended from is kept when ``carry(state)`` says it fits. Marks it the most
        recently used."""
        entry = self._entries.get(key)
        self.change = ""
        if (entry is not None and not restart and entry.map == loaded.map
                and entry.version != loaded.version and carry is not None):  # fmt: skip
            if entry.version in lineage(loaded) and carry(entry.value):
                entry.version, self.change = loaded.version, "carried"
        if entry is None or restart or entry.map != loaded.map or entry.version != loaded.version:
            self.change = "" if entry is None else "restarted"
            self.drop(key)
            value = start()
            size = self._size(value) + ENTRY_OVERHEAD_BYTES
            while self._entries and (
                len(self._entries) + 1 > self.max_items or self._bytes + size > self.max_bytes
            ):
                self._pop(next(iter(self._entries)))  # the least recently used makes room
            if self._lease is not None:
                try:
                    self._lease.reserve(size)  # raises when the server-wide budget is full
                except Exception:
                    del value  # not kept alive by the traceback until the error is answered
                    raise
            entry = _Entry(loaded.map, loaded.version, value, size)
            self._entries[key] = entry
            self._bytes += size
        self._entries.move_to_end(key)
        return entry.value

    def get(self, key: K) -> V | None:
        """``key``'s state as it is (any version), without marking it used."""
        entry = self._entries.get(key)
        return None if entry is None else entry.value

    def drop(self, key: K) -> None:
        """Forget ``key``'s state (nothing when there is none)."""
        if key in self._entries:
            self._pop(key)

    def clear(self) -> None:
        """Forget every state (released from the lease's budget)."""
        for key in list(self._entries):
            self._pop(key)

    def _pop(self, key: K) -> None:
        entry = self._entries.pop(key)
        self._bytes -= entry.nbytes
        if self._lease is not None:
            self._lease.release(entry.nbytes)

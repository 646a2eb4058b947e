"""Per-vehicle state that belongs to one map version, least recently used first forgotten.

A vehicle's sequence filter and its appearance adapter are both built from one served model
version: when the version (or the map) behind a key changes, or the caller asks for a
restart, the state starts afresh, so two models' evidence is never mixed. Entries beyond
``max_items``, or beyond ``max_bytes`` of state together, are dropped least recently used
first (the newest one always stays). Not thread-safe: callers serialise access.
"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Callable, Hashable
from dataclasses import dataclass
from typing import Generic, TypeVar

from service.core.model_store import LoadedModel

K = TypeVar("K", bound=Hashable)
V = TypeVar("V")


@dataclass
class _Entry(Generic[V]):
    map: str
    version: int
    value: V
    nbytes: int


class VehicleState(Generic[K, V]):
    """``key`` → state of ``loaded``'s version (:meth:`current`), bounded in count and bytes."""

    def __init__(self, max_items: int, max_bytes: int, nbytes: Callable[[V], int]) -> None:
        self.max_items = max_items
        self.max_bytes = max_bytes
        self._size = nbytes
        self._entries: OrderedDict[K, _Entry[V]] = OrderedDict()
        self._bytes = 0

    def __len__(self) -> int:
        return len(self._entries)

    @property
    def nbytes(self) -> int:
        """Bytes the states hold together."""
        return self._bytes

    def current(self, key: K, loaded: LoadedModel, start: Callable[[], V],
                restart: bool = False) -> V:  # fmt: skip
        """``key``'s state for ``loaded`` (``start()`` makes a new one when there is none, it
        belongs to another map or version, or ``restart``); marks it the most recently used."""
        entry = self._entries.get(key)
        if entry is None or restart or entry.map != loaded.map or entry.version != loaded.version:
            self.drop(key)
            value = start()
            entry = _Entry(loaded.map, loaded.version, value, self._size(value))
            self._entries[key] = entry
            self._bytes += entry.nbytes
        self._entries.move_to_end(key)
        while len(self._entries) > 1 and (
            len(self._entries) > self.max_items or self._bytes > self.max_bytes
        ):
            _, old = self._entries.popitem(last=False)  # the least recently used
            self._bytes -= old.nbytes
        return entry.value

    def drop(self, key: K) -> None:
        """Forget ``key``'s state (nothing when there is none)."""
        entry = self._entries.pop(key, None)
        if entry is not None:
            self._bytes -= entry.nbytes

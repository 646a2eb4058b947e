"""The ``vehicle_key`` each vehicle's statistics are kept under on the server, per map.

The server issues a key with a vehicle's first adapted answer and finds the vehicle's
statistics by it afterwards (:mod:`service.core.vehicle_adapters`); a client remembers it so
that ``localize(..., vehicle_id=...)`` continues the same drive without the caller handling
keys. Thread-safe.
"""

from __future__ import annotations

import threading


class VehicleKeys:
    def __init__(self) -> None:
        self._keys: dict[tuple[str, str], str] = {}
        self._lock = threading.Lock()

    def key(self, map_name: str, vehicle_id: str | None, given: str | None) -> str | None:
        """The key to send: ``given``, else the one remembered for the vehicle (if any)."""
        if given is not None or vehicle_id is None:
            return given
        with self._lock:
            return self._keys.get((map_name, vehicle_id))

    def remember(self, map_name: str, vehicle_id: str | None, key: str | None) -> None:
        if vehicle_id is not None and key is not None:
            with self._lock:
                self._keys[(map_name, vehicle_id)] = key

"""Appearance statistics of vehicles that send their frames one request at a time (REST).

A stream keeps each vehicle's adapter for as long as it is open (:mod:`service.core.streams`);
a vehicle that calls ``POST /v1/localize`` once per frame names itself with ``vehicle_id``
instead, and its adapter (:mod:`service.encoding.adaptation`) lives here between requests,
keyed by map and vehicle. An adapter belongs to one map version: when the served version
changes it restarts, like a stream's. The least recently seen vehicles are forgotten beyond
``max_vehicles`` or ``max_bytes`` (a forgotten vehicle starts again from the route's
statistics: its answers are then those of a fresh drive, never wrong ones). Requests of one
vehicle are adapted one at a time in the order they take the lock; with several API replicas
each keeps its own statistics of the vehicles it serves.
"""

from __future__ import annotations

import dataclasses
import threading
from collections import OrderedDict
from dataclasses import dataclass

import numpy as np

from service.core.localization import LocalizationService, LocalizeResult
from service.core.model_store import LoadedModel
from service.core.streams import MAX_VEHICLE_ID
from service.encoding.adaptation import AdaptationConfig, AppearanceAdapter, route_statistics
from service.errors import InvalidInputError, InvalidParameterError

MAX_VEHICLES = 10_000
MAX_BYTES = 256 * 1024 * 1024  # every vehicle's running statistics together


@dataclass
class _Entry:
    version: int
    adapter: AppearanceAdapter


class VehicleAdapters:
    """Thread-safe LRU of ``(map, vehicle_id)`` → adapter."""

    def __init__(self, config: AdaptationConfig | None = None, max_vehicles: int = MAX_VEHICLES,
                 max_bytes: int = MAX_BYTES) -> None:  # fmt: skip
        self.config = config or AdaptationConfig()
        self.max_vehicles = max_vehicles
        self.max_bytes = max_bytes
        self._entries: OrderedDict[tuple[str, str], _Entry] = OrderedDict()
        self._bytes = 0
        self._lock = threading.Lock()

    def __len__(self) -> int:
        return len(self._entries)

    @property
    def nbytes(self) -> int:
        return self._bytes

    def adapt(self, loaded: LoadedModel, vehicle_id: str, Q: np.ndarray, reset: bool = False) -> np.ndarray:
        """``Q`` (validated rows, the vehicle's next frames in order) adapted to the vehicle's
        earlier frames on ``loaded``'s map; ``reset`` forgets them first."""
        key = (loaded.map, vehicle_id)
        with self._lock:
            entry = self._entries.get(key)
            if entry is None or reset or entry.version != loaded.version:
                self._forget(key)
                entry = _Entry(loaded.version, AppearanceAdapter.for_model(loaded.model, self.config))
                self._entries[key] = entry
                self._bytes += entry.adapter.nbytes
            self._entries.move_to_end(key)
            out = entry.adapter.transform(Q)
            while len(self._entries) > 1 and (
                len(self._entries) > self.max_vehicles or self._bytes > self.max_bytes
            ):
                _, old = self._entries.popitem(last=False)  # the least recently seen vehicle
                self._bytes -= old.adapter.nbytes
            return out

    def _forget(self, key: tuple[str, str]) -> None:
        entry = self._entries.pop(key, None)
        if entry is not None:
            self._bytes -= entry.adapter.nbytes


def answer_vehicle(service: LocalizationService, adapters: VehicleAdapters, loaded: LoadedModel,
                   Q: np.ndarray, start: float, kind: str, vehicle_id: str | None,
                   adapt: bool | None) -> LocalizeResult:  # fmt: skip
    """Localize validated queries ``Q`` on ``loaded``, adapted to ``vehicle_id``'s earlier
    frames when adaptation is on for it (``adapt``; unset: ``GRIDPLACE_DRIVE_ADAPTATION``).
    Without a vehicle there is nothing to adapt to: ``adapt=True`` is then refused."""
    if vehicle_id is not None and len(vehicle_id) > MAX_VEHICLE_ID:
        raise InvalidInputError(f"vehicle_id is longer than {MAX_VEHICLE_ID} characters")
    if adapt and vehicle_id is None:
        raise InvalidInputError(
            "adaptation needs a vehicle_id: a query is adapted to the same vehicle's earlier "
            "queries", field="vehicle_id",
        )  # fmt: skip
    wanted = service.settings.drive_adaptation if adapt is None else adapt
    adapted = False
    if wanted and vehicle_id is not None:
        if route_statistics(loaded.model) is not None:
            Q, adapted = adapters.adapt(loaded, vehicle_id, Q), True
        elif adapt:
            raise InvalidParameterError(
                f"map {loaded.map!r} version {loaded.version} was trained without normalisation "
                "and keeps no route statistics to adapt to; send adaptation=false"
            )
    result = service.answer(loaded, Q, start, kind)
    return dataclasses.replace(result, adapted=adapted) if adapted else result

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

import numpy as np

from service.core.localization import LocalizationService, LocalizeResult
from service.core.model_store import LoadedModel
from service.core.streams import MAX_VEHICLE_ID
from service.core.vehicle_state import VehicleState
from service.encoding.adaptation import AdaptationConfig, AppearanceAdapter, adapts
from service.errors import InvalidInputError

MAX_VEHICLES = 10_000
MAX_BYTES = 256 * 1024 * 1024  # every vehicle's running statistics together


class VehicleAdapters:
    """Thread-safe LRU of ``(map, vehicle_id)`` → adapter."""

    def __init__(self, config: AdaptationConfig | None = None, max_vehicles: int = MAX_VEHICLES,
                 max_bytes: int = MAX_BYTES) -> None:  # fmt: skip
        self.config = config or AdaptationConfig()
        self._state: VehicleState[tuple[str, str], AppearanceAdapter] = VehicleState(
            max_vehicles, max_bytes, lambda a: a.nbytes)  # fmt: skip
        self._lock = threading.Lock()

    def __len__(self) -> int:
        return len(self._state)

    @property
    def nbytes(self) -> int:
        return self._state.nbytes

    def adapt(self, loaded: LoadedModel, vehicle_id: str, Q: np.ndarray, reset: bool = False) -> np.ndarray:
        """``Q`` (validated rows, the vehicle's next frames in order) adapted to the vehicle's
        earlier frames on ``loaded``'s map; ``reset`` forgets them first."""
        with self._lock:
            adapter = self._state.current(
                (loaded.map, vehicle_id), loaded,
                lambda: AppearanceAdapter.for_model(loaded.model, self.config), restart=reset,
            )  # fmt: skip
            return adapter.transform(Q)


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
    adapted = False
    if vehicle_id is not None and adapts(loaded.model, adapt, service.settings.drive_adaptation,
                                         f"map {loaded.map!r} version {loaded.version}"):  # fmt: skip
        Q, adapted = adapters.adapt(loaded, vehicle_id, Q), True
    result = service.answer(loaded, Q, start, kind)
    return dataclasses.replace(result, adapted=adapted) if adapted else result

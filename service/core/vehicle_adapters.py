"""Appearance statistics of vehicles that send their frames one request at a time (REST).

A stream keeps each vehicle's adapter for as long as it is open (:mod:`service.core.streams`);
a vehicle that calls ``POST /v1/localize`` once per frame names itself with ``vehicle_id``
instead, and its adapter (:mod:`service.encoding.adaptation`) lives here between requests.

**Whose state it is.** ``vehicle_id`` needs no authentication, so it cannot be what a
vehicle's state is found by: anyone who knows or guesses an id could otherwise send frames
under it (a frame far outside the statistics is no longer learnt from, but ordinary frames of
another drive would still pull them away) or reset it. State is kept under ``(map,
vehicle_id, vehicle_key)``: the first query of a vehicle comes without a key, and the server
issues one (128 random bits, answered as ``vehicle_key``) under which the statistics are then
kept; the vehicle sends it with every later query. A caller who does not know the key reaches
nothing but a drive of its own (a query without a key always starts one); a vehicle may also
bring its own key (22–128 random URL-safe characters, e.g. provisioned with the vehicle).
Only a digest of the key is held. ``reset`` with the key forgets the statistics before the
query. Nothing an unauthenticated caller sends can read, drive or reset another's statistics;
it can only make the server forget them sooner, by filling the store.

A query may name its condition (:mod:`service.core.query_conditions`): a new drive starts
from it, a running one moves to it; with none named the drive infers it from its first frames
when the version records conditions.

An adapter belongs to one map version: when the served version changes it restarts, like a
stream's. The least recently seen vehicles are forgotten beyond ``max_vehicles``
(``GRIDPLACE_MAX_REST_VEHICLES``) or ``max_bytes`` (``GRIDPLACE_REST_VEHICLE_STATE_MB``); a
forgotten vehicle that sends its key again starts again from the route's statistics, under
the same key (its answers are then those of a fresh drive, never wrong ones). Requests of one
vehicle are adapted one at a time in the order they take the lock; with several API replicas
each keeps its own statistics of the vehicles it serves.
"""

from __future__ import annotations

import dataclasses
import hashlib
import secrets
import threading

import numpy as np

from service.core.localization import LocalizationService, LocalizeResult
from service.core.model_store import LoadedModel
from service.core.streams import MAX_VEHICLE_ID
from service.core.vehicle_state import VehicleState
from service.core.query_conditions import continue_drive, new_drive
from service.encoding.adaptation import AdaptationConfig, AppearanceAdapter, adapts
from service.encoding.conditions import DEFAULT_INFERENCE_FRAMES
from service.errors import InvalidInputError

MAX_VEHICLES = 10_000
MAX_BYTES = 256 * 1024 * 1024  # every vehicle's running statistics together
_KEY_BYTES = 24  # an issued key: 192 random bits, 32 URL-safe characters

Key = tuple[str, str, bytes]  # map, vehicle_id, digest of the vehicle_key


def new_vehicle_key() -> str:
    return secrets.token_urlsafe(_KEY_BYTES)


class VehicleAdapters:
    """Thread-safe LRU of ``(map, vehicle_id, vehicle_key)`` → adapter."""

    def __init__(self, config: AdaptationConfig | None = None, max_vehicles: int = MAX_VEHICLES,
                 max_bytes: int = MAX_BYTES,
                 condition_frames: int = DEFAULT_INFERENCE_FRAMES) -> None:  # fmt: skip
        self.config = config or AdaptationConfig()
        self.condition_frames = condition_frames
        self._state: VehicleState[Key, AppearanceAdapter] = VehicleState(
            max_vehicles, max_bytes, lambda a: a.nbytes)  # fmt: skip
        self._lock = threading.Lock()

    def __len__(self) -> int:
        return len(self._state)

    @property
    def nbytes(self) -> int:
        return self._state.nbytes

    def adapt(self, loaded: LoadedModel, vehicle_id: str, Q: np.ndarray,
              vehicle_key: str | None = None, reset: bool = False,
              condition: str | None = None) -> tuple[np.ndarray, str, str]:  # fmt: skip
        """``Q`` (validated rows, the vehicle's next frames in order) adapted to the earlier
        frames the vehicle sent with ``vehicle_key`` on ``loaded``'s map (``reset`` forgets
        them first; a new drive starts from ``condition``,
        :mod:`service.core.query_conditions`), the key they are kept under (``vehicle_key``,
        or a new one when it is ``None``: a new drive) and the condition the drive started
        from."""
        key = new_vehicle_key() if vehicle_key is None else vehicle_key
        digest = hashlib.sha256(key.encode()).digest()
        with self._lock:
            fresh: list[bool] = []

            def start() -> AppearanceAdapter:
                fresh.append(True)
                return new_drive(loaded, self.config, condition, self.condition_frames)

            adapter = self._state.current((loaded.map, vehicle_id, digest), loaded, start,
                                          restart=reset)  # fmt: skip
            if not fresh:
                continue_drive(adapter, loaded, condition)
            return adapter.transform(Q), key, adapter.condition_name


def answer_vehicle(service: LocalizationService, adapters: VehicleAdapters, loaded: LoadedModel,
                   Q: np.ndarray, start: float, kind: str, vehicle_id: str | None,
                   adapt: bool | None, vehicle_key: str | None = None,
                   reset: bool | None = None,
                   condition: str | None = None) -> tuple[LocalizeResult, str | None]:  # fmt: skip
    """Localize validated queries ``Q`` on ``loaded``, adapted to ``vehicle_id``'s earlier
    frames sent with ``vehicle_key`` when adaptation is on for it (``adapt``; unset:
    ``GRIDPLACE_DRIVE_ADAPTATION``), and the key the vehicle's statistics are kept under
    (``None`` when the query was not adapted). Without a vehicle there is nothing to adapt
    to: ``adapt=True``, a key or ``reset`` are then refused."""
    if vehicle_id is not None and len(vehicle_id) > MAX_VEHICLE_ID:
        raise InvalidInputError(f"vehicle_id is longer than {MAX_VEHICLE_ID} characters")
    if vehicle_id is None:
        for name, value in (("adaptation", adapt), ("vehicle_key", vehicle_key), ("reset", reset)):
            if value:
                raise InvalidInputError(
                    f"{name} needs a vehicle_id: a query is adapted to the same vehicle's earlier "
                    "queries", field="vehicle_id",
                )  # fmt: skip
    key = None
    if vehicle_id is not None and adapts(loaded.model, adapt, service.settings.drive_adaptation,
                                         f"map {loaded.map!r} version {loaded.version}"):  # fmt: skip
        Q, key, used = adapters.adapt(loaded, vehicle_id, Q, vehicle_key, bool(reset), condition)
        result = service.answer(loaded, Q, start, kind)
        return dataclasses.replace(result, adapted=True, condition=used), key
    return service.answer(loaded, Q, start, kind, condition), key

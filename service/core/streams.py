"""Fleet streams: ordered frames of many vehicles, each optionally sequence-filtered.

Transport-agnostic glue over :class:`~service.core.localization.LocalizationService` (the
gRPC ``LocalizeStream`` uses it; a REST/WebSocket stream could use it unchanged). A frame is
validated and localized exactly as a single ``/localize`` query is (same validation, metrics
and hot-swap semantics); with ``sequence_filter`` the frame's scores over the route update the
vehicle's recursive Bayes filter (:mod:`service.encoding.sequence`), whose estimate is answered.

With appearance adaptation (:mod:`service.encoding.adaptation`; on for a frame when it asks,
or by the stream's default when it does not say) the vehicle's frames are standardised by the
running statistics of its own earlier frames before they are localized; the answer says
whether a frame was adapted (a map trained without normalisation has no route statistics to
adapt to: a frame that asked explicitly is refused, one that did not goes through unadapted).

A frame may name the condition it was taken in (``condition``,
:mod:`service.core.query_conditions`): a vehicle's adapter starts from that condition's
statistics (or, named on a later frame, moves to them); with none named, on a version that
records conditions, it infers the closest from the vehicle's first frames. An unadapted frame
is standardised by the condition it names. The answer's ``condition`` says which was used.

A vehicle's filter and adapter belong to one map *version*: when the served version changes
(an activation or rollback mid-stream), the map changes, or the client asks for a reset, they
restart, so scores of two different models are never mixed; turning the filter flag off
restarts the filter. A newly served version built from the vehicle's by appending traversals
(:func:`~service.core.vehicle_state.lineage`) takes the vehicle's filter over when it has as
many places, and its adapter when its route statistics are the ones the adapter standardises
to; the answer's
``vehicle_state`` says ``carried``, or ``restarted`` when a vehicle's state started afresh. Filters (adapters) of the least recently seen vehicles are dropped beyond
``max_vehicles`` or when the stream's filters (adapters) together would hold more than
``max_filter_bytes`` (``max_adapter_bytes``).

A stream's vehicles are its own: their state lives in the stream and only frames sent on it
reach it, so no other caller can read, drive or reset them. With a ``lease`` from the
server-wide :class:`~service.core.stream_budget.StreamBudget` every filter and adapter is also
reserved from the server's budget (a frame that needs one more than it holds is refused with
``CapacityError``); :meth:`FleetStream.close` drops them all and gives the lease back.

Adaptation is separate from validation (:meth:`FleetStream.prepare` names the frame's adapter
without applying it), so that the micro-batcher adapts the frames of all the vehicles of a
batch in one vectorised step (:func:`~service.encoding.adaptation.transform_rows`) with the
answers of one frame at a time.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass

import numpy as np

from service.core.localization import LocalizationService, LocalizeResult
from service.core.model_store import LoadedModel
from service.core.query_conditions import continue_drive, new_drive, standardise
from service.core.sequences import chunk_of, odometry_frames
from service.core.stream_budget import StreamLease
from service.core.vehicle_state import VehicleState
from service.encoding.adaptation import (
    AdaptationConfig,
    AppearanceAdapter,
    adapts,
    route_statistics,
)
from service.encoding.conditions import DEFAULT_INFERENCE_FRAMES
from service.encoding.drive_scoring import drive_scorer
from service.encoding.sequence import SequenceConfig
from service.encoding.tracking import DriveTracker
from service.errors import (
    DimensionMismatchError,
    EmptyInputError,
    InvalidInputError,
    UnavailableError,
)

MAX_VEHICLE_ID = 128
MAX_VEHICLES_PER_STREAM = 1024
MAX_FILTER_BYTES_PER_STREAM = 512 * 1024 * 1024  # the filters' posteriors, all vehicles together
MAX_ADAPTER_BYTES_PER_STREAM = 64 * 1024 * 1024  # the adapters' running statistics, together
#: a filter's Python objects beyond its posterior (its speed groups; tracemalloc: 3.4 kB)
FILTER_OVERHEAD_BYTES = 4096


@dataclass(slots=True)  # not frozen: a frozen dataclass costs 1.6 µs to make, this 0.3
class Frame:
    """One request of a stream: exactly one of ``descriptor`` (little-endian float32 bytes,
    ``d`` values) or ``image`` (encoded image bytes)."""

    vehicle_id: str
    sequence: int
    map: str
    descriptor: bytes | None = None
    image: bytes | None = None
    sequence_filter: bool = False
    reset: bool = False
    adapt: bool | None = None  # appearance adaptation; None: the stream's default
    odometry: float | None = None  # displacement since the previous frame, reference frames
    odometry_m: float | None = None  # the same in metres (the map's frame spacing converts it)
    condition: str | None = None  # the condition named (service.core.query_conditions)


@dataclass(slots=True)
class FrameAnswer:
    vehicle_id: str
    sequence: int
    map: str
    version: int
    index: int  # filtered estimate when ``filtered``, else the frame's own
    chunk: int
    confidence: float
    filtered: bool
    raw_index: int  # the frame's own estimate (what /localize answers)
    raw_confidence: float
    frames_used: int  # frames the filter combined since its start (1 unfiltered)
    latency_ms: float
    adapted: bool = False  # standardised by the vehicle's running statistics first
    vehicle_state: str = ""  # "carried" into a new version of the same places, or "restarted"
    condition: str = ""  # the condition the frame was standardised from ("": none)


def same_statistics(adapter: AppearanceAdapter, model: object) -> bool:
    """Whether ``adapter`` standardises to ``model``'s route statistics (a version appended
    from its own keeps them)."""
    stats = route_statistics(model)
    return stats is not None and np.array_equal(adapter.route_mean, stats.mean) and \
        np.array_equal(adapter.route_scale, stats.scale)


def one_descriptor(Q: np.ndarray, loaded: LoadedModel, what: str) -> np.ndarray:
    """``Q`` when it is one row (a frame, a single query), else a dimension error naming it."""
    if Q.shape[0] != 1:
        raise DimensionMismatchError(
            f"{what} carries one descriptor of d={loaded.n_features} values; "
            f"got {Q.shape[0] * loaded.n_features}",
            expected=loaded.n_features, got=int(Q.size),
        )  # fmt: skip
    return Q


class FleetStream:
    """The state of one open stream: a sequence filter and an adapter per vehicle. One
    stream's frames are answered one after another, in order (by the caller, or by the
    micro-batcher's worker); a lock keeps :meth:`close`, which may come from another thread
    while a frame is in flight, from interleaving with them (frames after it are refused)."""

    def __init__(
        self,
        service: LocalizationService,
        config: SequenceConfig | None = None,
        max_vehicles: int = MAX_VEHICLES_PER_STREAM,
        max_filter_bytes: int = MAX_FILTER_BYTES_PER_STREAM,
        adaptation: AdaptationConfig | None = None,
        adapt_by_default: bool = False,
        max_adapter_bytes: int = MAX_ADAPTER_BYTES_PER_STREAM,
        lease: StreamLease | None = None,
        condition_frames: int = DEFAULT_INFERENCE_FRAMES,
    ) -> None:
        self.service = service
        self.condition_frames = condition_frames
        self.config = config or SequenceConfig()
        self.max_vehicles = max_vehicles
        self.max_filter_bytes = max_filter_bytes
        self.adaptation = adaptation or AdaptationConfig()
        self.adapt_by_default = adapt_by_default
        self.max_adapter_bytes = max_adapter_bytes
        self.lease = lease
        self.closed = False
        self._lock = threading.Lock()
        self._filters: VehicleState[str, DriveTracker] = VehicleState(
            max_vehicles, max_filter_bytes, lambda f: f.max_nbytes + FILTER_OVERHEAD_BYTES, lease)  # fmt: skip
        self._adapters: VehicleState[str, AppearanceAdapter] = VehicleState(
            max_vehicles, max_adapter_bytes, lambda a: a.nbytes, lease)  # fmt: skip
        self._adapter_changes: dict[str, str] = {}  # a vehicle's adapter carried or restarted
        self._conditions: dict[str, str] = {}  # the condition of a vehicle's prepared frame

    def close(self) -> None:
        """Drop every vehicle's state and give the lease back (the stream has ended)."""
        with self._lock:
            self.closed = True
            self._filters.clear()
            self._adapters.clear()
            if self.lease is not None:
                self.lease.close()

    @property
    def vehicles(self) -> int:
        """Vehicles with filter history in this stream."""
        return len(self._filters)

    @property
    def adapted_vehicles(self) -> int:
        """Vehicles with appearance statistics in this stream."""
        return len(self._adapters)

    def answer(self, frame: Frame) -> FrameAnswer:
        """Localize one frame (raises a :class:`~service.errors.GridplaceError` for a bad one;
        the stream's other state is untouched by a failure)."""
        start = time.perf_counter()
        loaded, Q, adapter = self.prepare(frame)
        if adapter is not None:
            Q = adapter.transform(Q)
        raw = self.service.answer(loaded, Q, start, "stream")
        return self.finish(frame, loaded, Q, raw, start, adapter is not None)

    def prepare(self, frame: Frame) -> tuple[LoadedModel, np.ndarray, AppearanceAdapter | None]:
        """The served version (one reference for the frame: hot-swap safe), the frame's
        validated ``(1, d)`` query and the vehicle's adapter when the frame is adapted (not
        applied yet: the caller transforms the query, or many frames' with
        :func:`~service.encoding.adaptation.transform_rows`); raises for a bad frame."""
        if not frame.vehicle_id or len(frame.vehicle_id) > MAX_VEHICLE_ID:  # as REST's
            raise InvalidInputError(
                f"vehicle_id must name the vehicle in 1 to {MAX_VEHICLE_ID} characters, got "
                f"{len(frame.vehicle_id)}", vehicle_id_length=len(frame.vehicle_id),
            )  # fmt: skip
        loaded = self.service.served(frame.map)
        adapted = self._adapts(frame, loaded)
        Q = self._query(loaded, frame, np.float32 if adapted else np.float64)  # float32: adapted so
        if not adapted:
            Q, used = standardise(loaded, Q, frame.condition)
            if used is not None:
                with self._lock:
                    self._conditions[frame.vehicle_id] = used
            return loaded, Q, None
        with self._lock:
            self._check_open()
            return loaded, Q, self._adapter(frame, loaded)

    def finish(self, frame: Frame, loaded: LoadedModel, Q: np.ndarray, raw: LocalizeResult,
               start: float, adapted: bool) -> FrameAnswer:  # fmt: skip
        """The frame's answer from its raw localization (``raw``, e.g. computed in a batch
        with other frames): the vehicle's sequence filter is updated here, in frame order."""
        raw_index, raw_conf = int(raw.index[0]), float(raw.confidence[0])
        index, chunk, conf, used = raw_index, int(raw.chunk[0]), raw_conf, 1
        with self._lock:
            self._check_open()
            changes = {self._adapter_changes.pop(frame.vehicle_id, "")}
            condition = self._conditions.pop(frame.vehicle_id, "")
            if adapted and (adapter := self._adapters.get(frame.vehicle_id)) is not None:
                condition = adapter.condition_name
            if frame.sequence_filter:
                index, conf, used = self._track(frame, loaded, Q)
                chunk = int(chunk_of(loaded, index))
                changes.add(self._filters.change)
            else:
                self._filters.drop(frame.vehicle_id)
        state = "restarted" if "restarted" in changes else "carried" if "carried" in changes else ""
        return FrameAnswer(
            frame.vehicle_id, frame.sequence, loaded.map, loaded.version, index, chunk, conf,
            frame.sequence_filter, raw_index, raw_conf, used,
            (time.perf_counter() - start) * 1000.0, adapted, state, condition,
        )  # fmt: skip

    def _check_open(self) -> None:
        if self.closed:
            raise UnavailableError("the stream has ended")

    def _track(self, frame: Frame, loaded: LoadedModel, Q: np.ndarray) -> tuple[int, float, int]:
        """The vehicle's filtered estimate after ``Q``: index, confidence, frames used."""
        u = odometry_frames(loaded, 1, None if frame.odometry is None else [frame.odometry],
                            None if frame.odometry_m is None else [frame.odometry_m])  # fmt: skip
        odometry = None if u is None else float(u[0])
        scorer = drive_scorer(loaded.model)
        track = self._filters.current(
            frame.vehicle_id, loaded, lambda: DriveTracker(scorer, self.config),
            restart=frame.reset, carry=lambda f: f.n_frames == loaded.n_frames,
        )  # fmt: skip
        if track.scorer is not scorer:  # carried into a new version of the same places
            track.scorer = scorer
        estimate = track.update(scorer.prepare_many(Q)[0], odometry)
        return estimate.index, estimate.confidence, estimate.frames_used

    def _adapts(self, frame: Frame, loaded: LoadedModel) -> bool:
        """Whether ``frame`` is adapted on ``loaded`` (refused when it asks and cannot be)."""
        return adapts(loaded.model, frame.adapt, self.adapt_by_default,
                      f"map {loaded.map!r} version {loaded.version}")  # fmt: skip

    def _adapter(self, frame: Frame, loaded: LoadedModel) -> AppearanceAdapter:
        fresh: list[bool] = []

        def start() -> AppearanceAdapter:
            fresh.append(True)
            return new_drive(loaded, self.adaptation, frame.condition, self.condition_frames)

        adapter = self._adapters.current(
            frame.vehicle_id, loaded, start, restart=frame.reset,
            carry=lambda a: same_statistics(a, loaded.model),
        )  # fmt: skip
        if not fresh:
            continue_drive(adapter, loaded, frame.condition)
        if self._adapters.change:  # answered by finish(), after other vehicles' prepare()
            self._adapter_changes[frame.vehicle_id] = self._adapters.change
        return adapter

    def _query(self, loaded: LoadedModel, frame: Frame, dtype: type) -> np.ndarray:
        if frame.descriptor is not None and frame.image is not None:
            raise InvalidInputError("a frame carries a descriptor or an image, not both")
        if frame.image is not None:
            label = f"vehicle {frame.vehicle_id!r} frame {frame.sequence}"
            return self.service.query_images(loaded, [(label, frame.image)])
        if frame.descriptor is None:
            raise EmptyInputError("the frame has neither a descriptor nor an image")
        return one_descriptor(self.service.query_bytes(loaded, frame.descriptor, dtype=dtype),
                              loaded, "a stream frame")  # fmt: skip

    @property
    def filter_bytes(self) -> int:
        """Memory the vehicles' filters hold together."""
        return self._filters.nbytes

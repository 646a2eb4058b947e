"""``service.core.streams.FleetStream`` in-process over a real registry (SYNTHETIC route)."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np

from service.encoding.sequence import SequenceConfig
import pytest

from service.core.context import ServiceContext, build_context
from service.core.stream_budget import BudgetUse, StreamBudget
from service.core.streams import FILTER_OVERHEAD_BYTES, FleetStream, Frame
from service.core.vehicle_state import ENTRY_OVERHEAD_BYTES
from service.encoding import ModelParams, PhaseEncoder, build_model
from service.encoding.adaptation import ADAPTER_OVERHEAD_BYTES, AdaptationConfig, adapt_drive
from service.encoding.synthetic import smooth_route
from service.errors import (
    CapacityError,
    DimensionMismatchError,
    InvalidInputError,
    InvalidParameterError,
    UnavailableError,
)
from service.registry import Registry
from service.settings import Settings

N, D = 240, 32


@pytest.fixture(scope="module")
def ctx(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[ServiceContext, np.ndarray]]:
    data_dir: Path = tmp_path_factory.mktemp("streams")
    route = smooth_route(N, D, query_noise=0.3, seed=2)  # SYNTHETIC
    # the paper's mixed-radix code: its raw answers on these noisy queries leave the filter room
    params = {"encoder_preset": "ridge", "n_chunks": 3}
    model = build_model(ModelParams.parse(**params)).fit(route.reference)
    registry = Registry(data_dir)
    registry.publish("chunked", model, params=params, extractor=None, metrics={})
    bare = PhaseEncoder(n_patterns=2, trainer="ridge", normalize=False).fit(route.reference)
    registry.publish("bare", bare, params={"trainer": "ridge", "normalize": False},
                     extractor=None, metrics={})  # fmt: skip
    context = build_context(Settings(data_dir=data_dir), registry=registry)
    try:
        yield context, route.query
    finally:
        context.close()


def frame(Q: np.ndarray, row: int, vehicle: str = "v", **kw: object) -> Frame:
    return Frame(vehicle_id=vehicle, sequence=row, map="chunked",
                 descriptor=Q[row].astype("<f4").tobytes(), **kw)  # type: ignore[arg-type]  # fmt: skip


def test_filtered_estimates_name_their_chunk(ctx: tuple[ServiceContext, np.ndarray]) -> None:
    context, Q = ctx
    stream = FleetStream(context.service)
    answers = [stream.answer(frame(Q, r, sequence_filter=True)) for r in range(60, 120)]
    bounds = context.service.served("chunked").model.chunk_bounds_
    assert [a.frames_used for a in answers[:8]] == [1, 2, 3, 4, 5, 6, 7, 8]
    for a in answers:
        assert bounds[a.chunk] <= a.index < bounds[a.chunk + 1]
    truth = np.arange(60, 120)
    filtered = np.mean(np.abs(np.array([a.index for a in answers]) - truth) <= 2)
    raw = np.mean(np.abs(np.array([a.raw_index for a in answers]) - truth) <= 2)
    assert filtered > raw + 0.1 and filtered > 0.75


def test_the_least_recent_vehicle_is_forgotten(ctx: tuple[ServiceContext, np.ndarray]) -> None:
    context, Q = ctx
    stream = FleetStream(context.service, max_vehicles=2)
    for vehicle in ("a", "b", "a", "c"):  # c evicts b (a was seen more recently)
        stream.answer(frame(Q, 10, vehicle, sequence_filter=True))
    assert stream.vehicles == 2
    assert stream.answer(frame(Q, 11, "a", sequence_filter=True)).frames_used == 3
    assert stream.answer(frame(Q, 11, "b", sequence_filter=True)).frames_used == 1


def test_bad_frames_raise_the_hierarchy_and_leave_the_history(ctx: tuple[ServiceContext, np.ndarray]) -> None:
    context, Q = ctx
    stream = FleetStream(context.service)
    stream.answer(frame(Q, 5, sequence_filter=True))
    with pytest.raises(InvalidInputError, match="1 to 128 characters, got 200"):
        stream.answer(frame(Q, 6, "x" * 200))
    with pytest.raises(InvalidInputError, match="1 to 128 characters, got 0"):
        stream.answer(frame(Q, 6, ""))
    with pytest.raises(InvalidInputError, match="not both"):
        stream.answer(Frame("v", 7, "chunked", descriptor=b"\0" * 4 * D, image=b"png"))
    with pytest.raises(DimensionMismatchError, match="one descriptor"):
        stream.answer(Frame("v", 8, "chunked", descriptor=Q[:2].astype("<f4").tobytes()))
    assert stream.answer(frame(Q, 9, sequence_filter=True)).frames_used == 2


def test_filters_are_dropped_least_recent_first_beyond_the_byte_budget(
    ctx: tuple[ServiceContext, np.ndarray],
) -> None:
    context, Q = ctx
    # at most one whole posterior (S states × N frames of float32), the filter's objects, the entry
    per_vehicle = 4 * SequenceConfig().n_states * N + FILTER_OVERHEAD_BYTES + ENTRY_OVERHEAD_BYTES
    stream = FleetStream(context.service, max_filter_bytes=2 * per_vehicle)
    for vehicle in ("a", "b", "c"):
        stream.answer(frame(Q, 10, vehicle, sequence_filter=True))
    assert stream.vehicles == 2 and stream.filter_bytes == 2 * per_vehicle
    assert stream.answer(frame(Q, 11, "a", sequence_filter=True)).frames_used == 1  # a was dropped
    assert stream.answer(frame(Q, 11, "c", sequence_filter=True)).frames_used == 2
    stream.answer(frame(Q, 12, "c"))  # the flag off: c's filter is released
    assert stream.vehicles == 1 and stream.filter_bytes == per_vehicle


def test_each_vehicle_is_adapted_to_its_own_drive(ctx: tuple[ServiceContext, np.ndarray]) -> None:
    context, Q = ctx
    model = context.service.served("chunked").model
    stream = FleetStream(context.service, adaptation=AdaptationConfig(alpha=0.1),
                         adapt_by_default=True)  # fmt: skip
    rows = {"a": list(range(40)), "b": list(range(200, 160, -1))}
    got: dict[str, list[int]] = {"a": [], "b": []}
    for i in range(40):  # the two vehicles interleaved
        for v in ("a", "b"):
            answer = stream.answer(frame(Q, rows[v][i], v))
            assert answer.adapted and not answer.filtered
            got[v].append(answer.index)
    for v in ("a", "b"):
        drive = Q[rows[v]].astype(np.float32).astype(np.float64)
        expected = model.localize(adapt_drive(model, drive, AdaptationConfig(alpha=0.1))).index
        assert got[v] == expected.tolist()
    assert stream.adapted_vehicles == 2 and stream.vehicles == 0  # no filter was asked for
    # a frame may opt out, and a reset restarts the vehicle's statistics
    off = stream.answer(frame(Q, 7, "a", adapt=False))
    assert not off.adapted and off.index == int(model.localize(Q[7:8].astype(np.float32)).index[0])
    fresh = stream.answer(frame(Q, 7, "a", reset=True))
    assert fresh.adapted and fresh.index == off.index  # the first frame of a drive is unchanged


def test_a_map_without_route_statistics_is_not_adapted(ctx: tuple[ServiceContext, np.ndarray]) -> None:
    context, Q = ctx
    stream = FleetStream(context.service, adapt_by_default=True)
    row = Q[3].astype("<f4").tobytes()
    assert not stream.answer(Frame("v", 1, "bare", descriptor=row)).adapted
    with pytest.raises(InvalidParameterError, match="no route statistics"):
        stream.answer(Frame("v", 2, "bare", descriptor=row, adapt=True))
    assert stream.adapted_vehicles == 0


def test_adapters_are_dropped_least_recent_first(ctx: tuple[ServiceContext, np.ndarray]) -> None:
    context, Q = ctx
    # one adapter: a float32 mean, variance and last frame per column, its objects, the entry
    per_vehicle = 12 * D + ADAPTER_OVERHEAD_BYTES + ENTRY_OVERHEAD_BYTES
    stream = FleetStream(context.service, adapt_by_default=True, max_adapter_bytes=2 * per_vehicle)
    for vehicle in ("a", "b", "c"):
        stream.answer(frame(Q, 10, vehicle))
    assert stream.adapted_vehicles == 2
    limited = FleetStream(context.service, adapt_by_default=True, max_vehicles=1)
    for vehicle in ("a", "b"):
        limited.answer(frame(Q, 10, vehicle))
    assert limited.adapted_vehicles == 1


def test_the_server_wide_budget_bounds_streams_and_vehicles(ctx: tuple[ServiceContext, np.ndarray]) -> None:
    """Two streams share a budget of three vehicle states: the frame that needs a fourth is
    refused (the stream and its other vehicles go on); a closed stream gives its states and its
    place back, and frames sent after it closed are refused and keep nothing."""
    context, Q = ctx
    budget = StreamBudget(max_streams=2, max_states=3, max_bytes=1 << 30)
    one = FleetStream(context.service, adapt_by_default=True, lease=budget.open())
    two = FleetStream(context.service, adapt_by_default=True, lease=budget.open())
    with pytest.raises(CapacityError, match="GRIDPLACE_MAX_STREAMS=2"):
        budget.open()
    one.answer(frame(Q, 1, "a", sequence_filter=True))  # a filter and an adapter: two states
    two.answer(frame(Q, 1, "b"))
    with pytest.raises(CapacityError, match="GRIDPLACE_MAX_STREAM_VEHICLES=3"):
        two.answer(frame(Q, 2, "c"))
    assert two.answer(frame(Q, 2, "b")).adapted and two.adapted_vehicles == 1
    assert one.answer(frame(Q, 2, "a", sequence_filter=True)).frames_used == 2
    use = budget.use()
    assert (use.streams, use.states) == (2, 3) and use.nbytes == one.lease.nbytes + two.lease.nbytes
    one.close()
    assert budget.use().states == 1 and budget.use().streams == 1
    with pytest.raises(UnavailableError, match="ended"):
        one.answer(frame(Q, 3, "a"))
    assert one.adapted_vehicles == 0 and one.vehicles == 0
    three = FleetStream(context.service, adapt_by_default=True, lease=budget.open())
    three.answer(frame(Q, 1, "c", sequence_filter=True))
    two.close()
    three.close()
    assert budget.use() == BudgetUse(0, 0, 0)


def test_a_refused_state_is_not_kept(ctx: tuple[ServiceContext, np.ndarray]) -> None:
    context, Q = ctx
    budget = StreamBudget(max_streams=1, max_states=100, max_bytes=10_000)  # no room for a filter
    stream = FleetStream(context.service, lease=budget.open())
    with pytest.raises(CapacityError, match="GRIDPLACE_MAX_STREAM_STATE_MB"):
        stream.answer(frame(Q, 1, "a", sequence_filter=True))
    assert stream.vehicles == 0 and budget.use() == BudgetUse(1, 0, 0)
    assert not stream.answer(frame(Q, 2, "a")).filtered  # unfiltered frames need no state

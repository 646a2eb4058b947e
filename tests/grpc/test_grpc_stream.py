"""``LocalizeStream`` against a real ``gridplace serve``: order across concurrent vehicles,
bad messages answered in-stream, sequence filtering, and a model swap mid-stream."""

from __future__ import annotations

import asyncio
import time
from collections.abc import AsyncIterator, Sequence

import grpc
import numpy as np
import pytest
from grpc_helpers import D, N, Served, publish

from service.encoding.adaptation import adapt_drive
from service.encoding.sequence import SequenceConfig, sequence_localize
from service.encoding.synthetic import smooth_route
from service.grpc.gen import localization_pb2 as pb
from service.grpc.gen import localization_pb2_grpc as pb_grpc
from service.registry import Registry

pytestmark = pytest.mark.slow


def f32(x: np.ndarray) -> bytes:
    return np.ascontiguousarray(x, dtype="<f4").tobytes()


async def _requests(items: Sequence[pb.StreamRequest]) -> AsyncIterator[pb.StreamRequest]:
    for item in items:
        yield item


async def stream(channel: grpc.aio.Channel, items: Sequence[pb.StreamRequest]) -> list[pb.StreamResponse]:
    call = pb_grpc.LocalizationStub(channel).LocalizeStream(_requests(items))
    return [r async for r in call]


def run(served: Served, *batches: Sequence[pb.StreamRequest]) -> list[list[pb.StreamResponse]]:
    """Each batch on its own stream, all streams concurrently over one channel."""

    async def go() -> list[list[pb.StreamResponse]]:
        async with grpc.aio.insecure_channel(served.target) as channel:
            return list(await asyncio.gather(*(stream(channel, b) for b in batches)))

    return asyncio.run(go())


def test_concurrent_vehicles_get_every_answer_in_order(served: Served) -> None:
    n_streams, per_stream = 4, 1000  # 4 streams × 2 vehicles each, 4,000 frames
    batches, frames = [], []
    for s in range(n_streams):
        rows = [(7 * s + i) % N for i in range(per_stream)]
        frames.append(rows)
        batches.append([pb.StreamRequest(vehicle_id=f"truck-{s}-{i % 2}", sequence=i, map="route",
                                         descriptor=f32(served.query[r]))
                        for i, r in enumerate(rows)])  # fmt: skip
    answers = run(served, *batches)
    model = Registry(served.data_dir).load_model("route", 1)
    for sent, got, rows in zip(batches, answers, frames, strict=True):
        assert [(r.vehicle_id, r.sequence) for r in got] == [(q.vehicle_id, q.sequence) for q in sent]
        assert not any(r.HasField("error") for r in got)
        for parity in (0, 1):  # each vehicle's frames adapted to its own earlier frames
            assert [r.index for r in got[parity::2]] == drive_oracle(model, served.query, rows[parity::2]).tolist()
        assert all(r.version == 1 and not r.filtered and r.raw_index == r.index and r.adapted
                   for r in got)  # fmt: skip


def drive_oracle(model: object, query: np.ndarray, rows: Sequence[int]) -> np.ndarray:
    """What ``model`` answers in-process for ``query[rows]`` as one adapted drive."""
    Q = query[list(rows)].astype(np.float32).astype(np.float64)
    return model.localize(adapt_drive(model, Q)).index  # type: ignore[attr-defined]


def test_a_bad_message_is_answered_and_the_stream_goes_on(served: Served) -> None:
    good = f32(served.query[5])
    bad = [
        pb.StreamRequest(map="route", descriptor=f32(np.zeros(D - 1))),
        pb.StreamRequest(map="route", descriptor=f32(np.zeros(2 * D))),
        pb.StreamRequest(map="route", descriptor=f32(np.full(D, np.inf))),
        pb.StreamRequest(map="route"),
        pb.StreamRequest(map="nowhere", descriptor=good),
        pb.StreamRequest(map="parked", descriptor=good),
        pb.StreamRequest(map="route", image=b"\x89PNG"),
        pb.StreamRequest(map="imgs", image=b"not an image", sequence_filter=True),
    ]
    expected = ["INVALID_ARGUMENT"] * 4 + ["NOT_FOUND"] + ["FAILED_PRECONDITION"] * 2 + ["INVALID_ARGUMENT"]
    items = []
    for i, b in enumerate(bad):
        items.append(pb.StreamRequest(vehicle_id="car", sequence=2 * i, map="route", descriptor=good))
        b.vehicle_id, b.sequence = "car", 2 * i + 1
        items.append(b)
    items.append(pb.StreamRequest(vehicle_id="car", sequence=99, map="imgs", image=served.images[9]))
    (got,) = run(served, items)
    assert [r.sequence for r in got] == [q.sequence for q in items]
    errors = [r.error for r in got[1::2][: len(bad)]]
    assert [e.status for e in errors] == expected and all(e.message and e.code for e in errors)
    assert all(not r.HasField("error") and r.index == served.oracle[5] for r in got[0:-1:2])
    assert got[-1].index == served.image_oracle[9] and not got[-1].HasField("error")


def _precision(pred: list[int], truth: Sequence[int], tol: int = 2) -> float:
    return float(np.mean(np.abs(np.asarray(pred) - np.asarray(truth)) <= tol))


def test_sequence_filter_stabilises_a_noisy_route(served: Served) -> None:
    noisy = smooth_route(N, D, query_noise=1.0, seed=4).query  # same SYNTHETIC route, more noise
    truth = list(range(40, N))

    def drive(vehicle: str, flag: bool) -> list[pb.StreamRequest]:
        return [pb.StreamRequest(vehicle_id=vehicle, sequence=i, map="route", sequence_filter=flag,
                                 descriptor=f32(noisy[t])) for i, t in enumerate(truth)]  # fmt: skip

    filtered, raw = run(served, drive("seq", True), drive("plain", False))
    assert all(r.filtered for r in filtered) and not any(r.filtered for r in raw)
    assert [r.raw_index for r in filtered] == [r.index for r in raw]  # same frames, same model
    assert [r.frames_used for r in filtered[:8]] == [1, 2, 3, 4, 5, 6, 7, 8]
    p_raw = _precision([r.index for r in raw], truth)
    p_seq = _precision([r.index for r in filtered], truth)
    assert p_raw < 0.9 and p_seq > p_raw + 0.1, (p_raw, p_seq)
    # the stream answers what the library filter answers on the served artifact, for the
    # vehicle's drive adapted as the stream adapts it (its default)
    model = Registry(served.data_dir).load_model("route", 1)
    drive_rows = adapt_drive(model, noisy[truth].astype(np.float32).astype(np.float64))
    track = sequence_localize(model, drive_rows, SequenceConfig())
    assert [r.index for r in filtered] == track.index.tolist()


def test_reset_and_turning_the_filter_off_restart_the_history(served: Served) -> None:
    def req(i: int, **kw: bool) -> pb.StreamRequest:
        return pb.StreamRequest(vehicle_id="bus", sequence=i, map="route",
                                descriptor=f32(served.query[100 + i]), **kw)  # fmt: skip

    items = [req(0, sequence_filter=True), req(1, sequence_filter=True),
             req(2, sequence_filter=True, reset_sequence=True), req(3, sequence_filter=True),
             req(4), req(5, sequence_filter=True)]  # fmt: skip
    (got,) = run(served, items)
    assert [r.frames_used for r in got] == [1, 2, 1, 2, 1, 1]
    assert [r.filtered for r in got] == [True, True, True, True, False, True]


def test_a_new_version_mid_stream_keeps_the_stream_and_says_so(served: Served) -> None:
    async def go() -> list[pb.StreamResponse]:
        async with grpc.aio.insecure_channel(served.target) as channel:
            call = pb_grpc.LocalizationStub(channel).LocalizeStream()
            got: list[pb.StreamResponse] = []
            deadline = time.monotonic() + 30
            i = 0
            while time.monotonic() < deadline:
                await call.write(pb.StreamRequest(vehicle_id="van", sequence=i, map="swap",
                                                  sequence_filter=True,
                                                  descriptor=f32(served.query[i % N])))  # fmt: skip
                got.append(await call.read())
                if i == 50:  # activate a new version while the stream is open
                    await asyncio.to_thread(publish, served.data_dir, "swap",
                                            served.reference[::-1].copy(), None, True)  # fmt: skip
                if got[-1].version == 2 and len([r for r in got if r.version == 2]) >= 20:
                    break
                i += 1
            await call.done_writing()
            assert await call.read() == grpc.aio.EOF
            return got

    got = asyncio.run(go())
    versions = [r.version for r in got]
    assert versions[0] == 1 and versions[-1] == 2 and versions == sorted(versions)
    assert [r.sequence for r in got] == list(range(len(got)))
    assert not any(r.HasField("error") for r in got)
    first_v2 = versions.index(2)
    assert got[first_v2].frames_used == 1 and got[first_v2 - 1].frames_used == first_v2  # restarted
    # each version answers exactly as its artifact does, the vehicle's appearance statistics
    # restarting with v2 (the route reversed) like its filter
    registry = Registry(served.data_dir)
    seq = [r.sequence % N for r in got]
    v1 = drive_oracle(registry.load_model("swap", 1), served.query, seq[:first_v2])
    v2 = drive_oracle(registry.load_model("swap", 2), served.query, seq[first_v2:])
    assert [r.raw_index for r in got] == v1.tolist() + v2.tolist()
    assert all(r.adapted for r in got)


def test_frames_may_turn_adaptation_off(served: Served) -> None:
    rows = list(range(40, 100))
    items = [pb.StreamRequest(vehicle_id="plain", sequence=i, map="route", descriptor=f32(served.query[r]),
                              adaptation=pb.ADAPTATION_OFF if i % 2 else pb.ADAPTATION_ON)
             for i, r in enumerate(rows)]  # fmt: skip
    (got,) = run(served, items)
    model = Registry(served.data_dir).load_model("route", 1)
    assert [r.adapted for r in got] == [i % 2 == 0 for i in range(len(rows))]
    assert [r.index for r in got[1::2]] == served.oracle[rows[1::2]].tolist()  # as sent
    # the adapted frames form the vehicle's drive: the others neither use nor move its statistics
    assert [r.index for r in got[0::2]] == drive_oracle(model, served.query, rows[0::2]).tolist()


def test_odometry_per_frame_moves_the_vehicle_and_bad_odometry_is_refused(served: Served) -> None:
    """Frames 30…149, the first ten as recorded and the rest drowned in noise: with exact
    odometry the estimate follows the vehicle, without it much less often."""
    rows = list(range(30, 150))
    rng = np.random.default_rng(0)
    spread = float(served.query.std())

    def drive(vehicle: str, odometry: float | None) -> list[pb.StreamRequest]:
        out = []
        for k, i in enumerate(rows):
            q = served.query[i] + (0 if k < 10 else rng.normal(0, 3 * spread, D))
            req = pb.StreamRequest(vehicle_id=vehicle, sequence=k, map="route", descriptor=f32(q),
                                   sequence_filter=True, adaptation=pb.ADAPTATION_OFF)  # fmt: skip
            if odometry is not None:
                req.odometry = odometry
            out.append(req)
        return out

    bad = [pb.StreamRequest(vehicle_id="odo", sequence=1000 + j, map="route",
                            descriptor=f32(served.query[5]), sequence_filter=True, odometry=u)
           for j, u in enumerate([float("nan"), float("inf"), 1e7])]  # fmt: skip
    with_odo, without = run(served, drive("odo", 1.0) + bad, drive("blind", None))
    truth = np.array(rows[10:])
    hit = np.mean(np.abs(np.array([r.index for r in with_odo[10 : len(rows)]]) - truth) <= 2)
    blind = np.mean(np.abs(np.array([r.index for r in without[10:]]) - truth) <= 2)
    assert hit > 0.9 and hit > blind + 0.1, (hit, blind)
    assert [r.error.status for r in with_odo[len(rows):]] == ["INVALID_ARGUMENT"] * 3
    assert "odometry" in with_odo[len(rows)].error.message


def test_odometry_in_metres_needs_the_maps_frame_spacing(served: Served) -> None:
    req = pb.StreamRequest(vehicle_id="metres", sequence=1, map="route", sequence_filter=True,
                           descriptor=f32(served.query[5]), odometry_m=2.0)  # fmt: skip
    both = pb.StreamRequest(vehicle_id="metres", sequence=2, map="route", sequence_filter=True,
                            descriptor=f32(served.query[6]), odometry=1.0, odometry_m=2.0)  # fmt: skip
    (got,) = run(served, [req, both])
    assert got[0].error.status == "FAILED_PRECONDITION" and "frame spacing" in got[0].error.message
    assert got[1].error.status == "INVALID_ARGUMENT" and "not both" in got[1].error.message

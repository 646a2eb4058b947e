"""``POST /v1/localize/sequence`` on a real ``gridplace serve`` process: the typed clients,
raw JSON and binary bodies, the filter parameters and their bounds (SYNTHETIC route)."""

from __future__ import annotations

import asyncio
import base64
from pathlib import Path

import httpx
import numpy as np
import pytest
from client_helpers import TOKEN

from service.api.process import ServerProcess
from service.client import AsyncGridplaceClient, GridplaceClient, Job
from service.encoding.adaptation import adapt_drive
from service.encoding.sequence import SequenceConfig, sequence_localize
from service.errors import InvalidParameterError, NotFoundError

Route = tuple[np.ndarray, np.ndarray]


def _oracle(data_dir: Path, version: int, Q: np.ndarray, config: SequenceConfig,
            adapted: bool = True) -> list[int]:  # fmt: skip
    """What the stored artifact and the library filter answer in-process (the drive adapted
    to its own statistics first, as the server does by default)."""
    from service.registry import Registry

    model = Registry(data_dir).load_model("synth", version)
    Q = Q.astype(np.float32).astype(np.float64)
    if adapted:
        Q = adapt_drive(model, Q)
    return sequence_localize(model, Q, config).index.tolist()


def _raw(data_dir: Path, version: int, Q: np.ndarray) -> list[int]:
    from service.registry import Registry

    model = Registry(data_dir).load_model("synth", version)
    return model.localize(adapt_drive(model, Q.astype(np.float32).astype(np.float64))).index.tolist()


def test_the_client_gets_the_library_filter_answers(
    gp: GridplaceClient, synth: Job, route: Route, data_dir: Path
) -> None:
    Q = route[1][20:140]
    got = gp.localize_sequence("synth", Q)
    assert got.n == 120 and got.map == "synth"
    assert got.adapted and got.index == _oracle(data_dir, got.version, Q, SequenceConfig())
    assert got.raw_index == _raw(data_dir, got.version, Q)
    plain = gp.localize_sequence("synth", Q, adaptation=False)
    assert not plain.adapted and plain.raw_index == gp.localize_batch("synth", Q).index
    assert plain.index == _oracle(data_dir, got.version, Q, SequenceConfig(), adapted=False)
    assert got.filter == SequenceConfig().model_dump()
    assert all(0.0 <= c <= 1.0 for c in got.confidence) and len(got.speed) == 120
    truth = np.arange(20, 140)
    assert np.mean(np.abs(np.array(got.index) - truth) <= 3) >= np.mean(
        np.abs(np.array(got.raw_index) - truth) <= 3
    )
    custom = gp.localize_sequence("synth", Q, emission_scale=0.3, reverse=True)
    assert custom.filter["emission_scale"] == 0.3 and custom.filter["reverse"] is True
    config = SequenceConfig(emission_scale=0.3, reverse=True)
    assert custom.index == _oracle(data_dir, custom.version, Q, config)


def test_json_and_base64_bodies_equal_the_binary_one(
    server: ServerProcess, synth: Job, route: Route
) -> None:
    Q = route[1][:60].astype(np.float32)
    url = server.url + "/v1/localize/sequence"
    binary = httpx.post(
        url,
        params={"map": "synth", "d": Q.shape[1], "max_speed": 3},
        content=Q.tobytes(),
        headers={"Content-Type": "application/octet-stream"},
    )
    as_json = httpx.post(
        url, json={"map": "synth", "descriptors": Q.tolist(), "filter": {"max_speed": 3}}
    )
    as_b64 = httpx.post(
        url,
        json={
            "map": "synth",
            "filter": {"max_speed": 3},
            "descriptors_b64": base64.b64encode(Q.tobytes()).decode(),
        },
    )
    for r in (binary, as_json, as_b64):
        assert r.status_code == 200, r.text
        assert r.json()["filter"]["max_speed"] == 3.0
    assert binary.json()["index"] == as_json.json()["index"] == as_b64.json()["index"]


@pytest.mark.parametrize(
    ("kwargs", "status", "code", "match"),
    [
        (
            {"json": {"map": "synth", "descriptors": [[0.0] * 63]}},
            400,
            "dimension_mismatch",
            "expects 64",
        ),
        ({"json": {"map": "synth", "descriptors": []}}, 422, "validation_error", "at least 1"),
        (
            {
                "json": {"map": "synth", "descriptors": [[0.0] * 64]},
                "params": {"speed_step": "0.001"},
            },
            400,
            "invalid_parameter",
            "more than 64",
        ),
        (
            {"json": {"map": "synth", "descriptors": [[0.0] * 64], "filter": {"max_speed": 0.1}}},
            400,
            "invalid_parameter",
            "below min_speed",
        ),
        (
            {"json": {"map": "synth", "descriptors": [[0.0] * 64], "filter": {"speed": 1}}},
            422,
            "validation_error",
            "filter.speed",
        ),
        (
            {
                "json": {"map": "synth", "descriptors": [[0.0] * 64], "filter": {"reverse": True}},
                "params": {"reverse": "false"},
            },
            400,
            "invalid_input",
            "not both",
        ),
        (
            {
                "json": {"map": "synth", "descriptors": [[0.0] * 64]},
                "params": {"emission_scale": "0"},
            },
            422,
            "validation_error",
            "emission_scale",
        ),
        (
            {
                "json": {"map": "synth", "descriptors": [[0.0] * 64]},
                "params": {"emision_scale": "1"},
            },
            400,
            "invalid_input",
            "emision_scale",
        ),
        (
            {"content": b"\0" * 12, "headers": {"Content-Type": "application/octet-stream"}},
            400,
            "invalid_input",
            "map",
        ),
        ({"json": {"map": "nowhere", "descriptors": [[0.0] * 64]}}, 404, "not_found", "nowhere"),
    ],
)
def test_bad_requests_are_4xx_naming_the_problem(
    server: ServerProcess, synth: Job, kwargs, status: int, code: str, match: str
) -> None:
    r = httpx.post(server.url + "/v1/localize/sequence", **kwargs)
    assert r.status_code == status, r.text
    assert r.json()["error"] == code and match in r.json()["message"]


def test_client_errors_map_back_to_the_hierarchy(
    gp: GridplaceClient, synth: Job, route: Route
) -> None:
    # static bounds and unknown names are refused before anything is sent …
    with pytest.raises(InvalidParameterError, match="relocalization"):
        gp.localize_sequence("synth", route[1][:5], relocalization=2.0)
    with pytest.raises(InvalidParameterError, match="speed"):
        gp.localize_sequence("synth", route[1][:5], speed=1.0)
    # … rules across options are the server's (a 400 naming them), unknown maps a 404
    with pytest.raises(InvalidParameterError, match="below min_speed"):
        gp.localize_sequence("synth", route[1][:5], max_speed=0.2)
    with pytest.raises(NotFoundError):
        gp.localize_sequence("nowhere", route[1][:5])


def test_the_async_client(server: ServerProcess, synth: Job, route: Route) -> None:
    Q = route[1][:40]

    async def main() -> tuple[list[int], list[int]]:
        async with AsyncGridplaceClient(server.url, token=TOKEN) as agp:
            a, b = await asyncio.gather(
                agp.localize_sequence("synth", Q), agp.localize_sequence("synth", Q, max_speed=3.0)
            )
            assert b.filter["max_speed"] == 3.0
            return a.index, b.index

    hmm, _ = asyncio.run(main())
    with GridplaceClient(server.url) as gp:
        assert hmm == gp.localize_sequence("synth", Q).index


def test_odometry_per_row_reaches_the_filter_and_bad_odometry_is_a_4xx(
    gp: GridplaceClient, synth: Job, route: Route, data_dir: Path
) -> None:
    Q = route[1][20:140]
    steps: list[float | None] = [1.0] * 120
    steps[5] = None  # a frame without odometry
    got = gp.localize_sequence("synth", Q, odometry=steps, adaptation=False)
    from service.registry import Registry

    model = Registry(data_dir).load_model("synth", got.version)
    want = sequence_localize(model, Q.astype(np.float32).astype(np.float64), SequenceConfig(),
                             odometry=steps)  # fmt: skip
    assert got.index == want.index.tolist()
    body = {"map": "synth", "descriptors": Q[:3].tolist()}
    with httpx.Client(base_url=gp.base_url) as raw:
        for odo, needle in (([1.0, 2.0], "expected 3 odometry values"),
                            ([1.0, 1e9, 1.0], "exceeds"), ([1.0, "x", 1.0], "odometry")):  # fmt: skip
            r = raw.post("/v1/localize/sequence", json={**body, "odometry": odo})
            assert 400 <= r.status_code < 500 and needle in r.text, r.text
        r = raw.post("/v1/localize/sequence", content=b'{"map": "synth", "descriptors": '
                     + str(Q[:3].tolist()).encode() + b', "odometry": [1, NaN, 1]}',
                     headers={"Content-Type": "application/json"})  # fmt: skip
        assert 400 <= r.status_code < 500, r.text


def test_odometry_in_metres_uses_the_spacing_recorded_at_upload(
    gp: GridplaceClient, synth: Job, route: Route, data_dir: Path
) -> None:
    from client_helpers import wait_serving

    job = gp.upload_route("spaced", route[0], trainer="ridge", frame_spacing_m=2.0)
    done = gp.wait_for_job(job.id, timeout=90, poll_interval=0.05)
    assert done.version is not None
    wait_serving(gp, "spaced", done.version)
    assert gp.get_map("spaced").active.params["frame_spacing_m"] == 2.0  # type: ignore[union-attr]
    Q = route[1][20:80]
    with httpx.Client(base_url=gp.base_url, timeout=60) as raw:
        body = {"map": "spaced", "descriptors": Q.tolist(), "adaptation": False}
        in_m = raw.post("/v1/localize/sequence", json={**body, "odometry_m": [2.0] * 60})
        in_frames = raw.post("/v1/localize/sequence", json={**body, "odometry": [1.0] * 60})
        assert in_m.status_code == 200 and in_m.json()["index"] == in_frames.json()["index"]
        both = raw.post("/v1/localize/sequence",
                        json={**body, "odometry": [1.0] * 60, "odometry_m": [2.0] * 60})  # fmt: skip
        assert both.status_code == 400 and "not both" in both.text
        unspaced = raw.post("/v1/localize/sequence",
                            json={**body, "map": "synth", "odometry_m": [2.0] * 60})  # fmt: skip
        assert unspaced.status_code == 409 and "frame spacing" in unspaced.text
    with pytest.raises(InvalidParameterError, match="frame_spacing_m"):
        gp.upload_route("spaced", route[0], trainer="ridge", frame_spacing_m=-1.0)

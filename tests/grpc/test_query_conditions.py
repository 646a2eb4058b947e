"""Condition tags at query time, through a real server (REST and gRPC): a map trained on one
condition, a traversal of another (a per-column gain and offset, tagged ``season=winter``)
appended; queries of that condition named, inferred, or sent as they are. SYNTHETIC route
(noisier than the package's, so that the condition's statistics matter), default model."""

from __future__ import annotations

import asyncio
import base64
import io
import json
import time
from pathlib import Path
from typing import Any

import grpc
import httpx
import numpy as np
import pytest
from grpc_helpers import TOKEN, Served

from service.encoding import ModelParams, build_model
from service.encoding.synthetic import smooth_route
from service.grpc.gen import localization_pb2 as pb
from service.grpc.gen import localization_pb2_grpc as pb_grpc

AUTH = {"Authorization": f"Bearer {TOKEN}"}
N, HALF = 300, 150


def _npy(X: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.save(buf, X, allow_pickle=False)
    return buf.getvalue()


@pytest.fixture(scope="module")
def seasons(served: Served) -> dict[str, Any]:
    """Map ``seasons``: v1 on the reference, v2 = v1 + winter half A tagged, active."""
    from service.registry import Registry

    route = smooth_route(N, 64, query_noise=1.5, seed=4)
    rng = np.random.default_rng(3)
    winter = route.query * rng.uniform(0.3, 3.0, 64) + rng.normal(0.0, 2.0, 64)
    Registry(served.data_dir).publish("seasons", build_model(ModelParams()).fit(route.reference),
                                      params={}, extractor=None, metrics={}, activate=True)  # fmt: skip
    r = httpx.post(f"{served.srv.url}/v1/maps/seasons/versions/1/traversals", headers=AUTH,
                   files=[("file", ("w.npy", _npy(winter[:HALF])))],
                   data={"tag": "season=winter", "activate": "true"}, timeout=60)  # fmt: skip
    assert r.status_code == 201, r.text
    deadline = time.monotonic() + 20
    while httpx.get(f"{served.srv.url}/v1/maps/seasons", headers=AUTH).json()["serving_version"] != 2:
        assert time.monotonic() < deadline, "version 2 was never served"
        time.sleep(0.05)
    return {"url": served.srv.url, "B": winter[HALF:].astype(np.float32)}


def _batch(url: str, B: np.ndarray, **extra: Any) -> dict[str, Any]:
    r = httpx.post(f"{url}/v1/localize/batch", json={"map": "seasons", "descriptors": B.tolist(), **extra})
    assert r.status_code == 200, r.text
    return r.json()  # type: ignore[no-any-return]


def _hits(index: list[int]) -> float:
    return float(np.mean(np.asarray(index) == np.arange(HALF, N)))


def test_naming_the_condition_changes_and_improves_the_answers(seasons: dict[str, Any]) -> None:
    url, B = seasons["url"], seasons["B"]
    sent = _batch(url, B)
    named = _batch(url, B, condition="season=winter")
    assert "condition" not in sent and named["condition"] == "season=winter"
    assert _hits(named["index"]) >= _hits(sent["index"]) + 0.04, (_hits(named["index"]), _hits(sent["index"]))
    assert _batch(url, B, condition="auto")["condition"] == "season=winter"
    assert _batch(url, B, condition="reference")["index"] == sent["index"]
    binary = httpx.post(f"{url}/v1/localize/batch", params={"map": "seasons", "condition": "season=winter"},
                        content=B.astype("<f4").tobytes(),
                        headers={"Content-Type": "application/octet-stream"})  # fmt: skip
    assert binary.status_code == 200 and binary.json()["index"] == named["index"]
    one = httpx.post(f"{url}/v1/localize", json={
        "map": "seasons", "condition": "season=winter",
        "descriptor_b64": base64.b64encode(B[0].astype("<f4").tobytes()).decode()})  # fmt: skip
    assert one.status_code == 200, one.text
    assert one.json()["condition"] == "season=winter" and one.json()["index"] == named["index"][0]


def test_an_unknown_condition_is_a_400_naming_the_known_ones(seasons: dict[str, Any]) -> None:
    url, B = seasons["url"], seasons["B"]
    for path, body in (("/v1/localize", {"descriptor": B[0].tolist()}),
                       ("/v1/localize/batch", {"descriptors": B[:2].tolist()}),
                       ("/v1/localize/sequence", {"descriptors": B[:2].tolist()})):  # fmt: skip
        r = httpx.post(url + path, json={"map": "seasons", "condition": "season=summer", **body})
        assert r.status_code == 400, (path, r.text)
        err = r.json()
        assert err["error"] == "unknown_condition", err
        assert "season=winter" in err["message"] and "reference" in err["message"]
    r = httpx.post(f"{url}/v1/localize/batch", json={"map": "seasons", "condition": "",
                                                     "descriptors": B[:1].tolist()})  # fmt: skip
    assert 400 <= r.status_code < 500


def test_drives_infer_the_condition_or_start_from_the_named_one(seasons: dict[str, Any]) -> None:
    url, B = seasons["url"], seasons["B"]

    def drive(**extra: Any) -> dict[str, Any]:
        r = httpx.post(f"{url}/v1/localize/sequence",
                       json={"map": "seasons", "descriptors": B[:40].tolist(), **extra})  # fmt: skip
        assert r.status_code == 200, r.text
        return r.json()  # type: ignore[no-any-return]

    inferred, named = drive(), drive(condition="season=winter")
    assert inferred["adapted"] and inferred["condition"] == named["condition"] == "season=winter"
    assert drive(condition="reference")["condition"] == "reference"
    assert drive(condition="season=winter", adaptation=False)["condition"] == "season=winter"
    key, answers = None, []
    for row in B[:12]:  # a vehicle querying one frame at a time
        body: dict[str, Any] = {"map": "seasons", "vehicle_id": "van", "descriptor": row.tolist()}
        if key:
            body["vehicle_key"] = key
        got = httpx.post(f"{url}/v1/localize", json=body).json()
        key = got["vehicle_key"]
        answers.append(got)
    assert all(a["adapted"] for a in answers) and answers[-1]["condition"] == "season=winter"


def test_a_stream_vehicle_infers_or_names_its_condition(seasons: dict[str, Any], served: Served) -> None:
    B = seasons["B"]

    async def go() -> list[pb.StreamResponse]:
        async with grpc.aio.insecure_channel(served.target) as channel:
            call = pb_grpc.LocalizationStub(channel).LocalizeStream()
            got = []
            frames = [("auto-van", "", B[i]) for i in range(12)]
            frames += [("ref-van", "reference", B[0]), ("bad-van", "season=summer", B[0]),
                       ("named-van", "season=winter", B[0])]  # fmt: skip
            for i, (vehicle, condition, row) in enumerate(frames):
                await call.write(pb.StreamRequest(vehicle_id=vehicle, sequence=i, map="seasons",
                                                  condition=condition,
                                                  descriptor=row.astype("<f4").tobytes()))  # fmt: skip
                got.append(await call.read())
            await call.done_writing()
            return got

    got = asyncio.run(go())
    auto, ref, bad, named = got[:12], got[12], got[13], got[14]
    assert all(r.adapted and not r.HasField("error") for r in auto)
    assert auto[-1].condition == "season=winter"
    assert ref.condition == "reference" and named.condition == "season=winter"
    assert bad.error.code == "unknown_condition" and bad.error.status == "INVALID_ARGUMENT"
    assert "season=winter" in bad.error.message
    assert named.raw_index != ref.raw_index or named.confidence != ref.confidence


def test_the_client_and_cli_name_the_condition(seasons: dict[str, Any], tmp_path: Path) -> None:
    from typer.testing import CliRunner

    from service.cli import app
    from service.client import GridplaceClient

    url, B = seasons["url"], seasons["B"]
    with GridplaceClient(url) as gp:
        named = gp.localize_batch("seasons", B, condition="season=winter")
        assert named.condition == "season=winter"
        assert named.index == _batch(url, B, condition="season=winter")["index"]
        assert gp.localize("seasons", B[0], condition="auto").condition == "season=winter"
        drive = gp.localize_sequence("seasons", B[:20], condition="season=winter")
        assert drive.condition == "season=winter" and drive.adapted
        assert gp.localize_sequence("seasons", B[:20], odometry=[1.0] * 20,
                                    condition="reference").condition == "reference"  # fmt: skip
    path = tmp_path / "b.npy"
    np.save(path, B[:3])
    env = {"GRIDPLACE_URL": url, "COLUMNS": "200"}
    runner = CliRunner()
    r = runner.invoke(app, ["client", "localize", "seasons", "--npy", str(path),
                            "--condition", "season=winter", "--json"], env=env)  # fmt: skip
    assert r.exit_code == 0, r.output
    assert json.loads(r.output)["condition"] == "season=winter"
    r = runner.invoke(app, ["client", "localize", "seasons", "--npy", str(path),
                            "--condition", "season=summer"], env=env)  # fmt: skip
    assert r.exit_code == 2 and "season=winter" in r.output, r.output


def test_grpc_localize_names_the_condition(seasons: dict[str, Any], served: Served) -> None:
    B = seasons["B"]

    async def go() -> tuple[pb.LocalizeResponse, pb.LocalizeResponse, grpc.RpcError]:
        async with grpc.aio.insecure_channel(served.target) as channel:
            stub = pb_grpc.LocalizationStub(channel)
            data = B.astype("<f4").tobytes()
            sent = await stub.Localize(pb.LocalizeRequest(map="seasons", descriptor=data))
            named = await stub.Localize(pb.LocalizeRequest(map="seasons", descriptor=data,
                                                           condition="season=winter"))  # fmt: skip
            try:
                await stub.Localize(pb.LocalizeRequest(map="seasons", descriptor=data,
                                                       condition="season=summer"))  # fmt: skip
            except grpc.RpcError as exc:
                return sent, named, exc
            raise AssertionError("an unknown condition was answered")

    sent, named, refused = asyncio.run(go())
    assert sent.condition == "" and named.condition == "season=winter"
    assert [m.index for m in named.matches] == _batch(seasons["url"], B, condition="season=winter")["index"]
    assert [m.index for m in sent.matches] != [m.index for m in named.matches]
    assert refused.code() == grpc.StatusCode.INVALID_ARGUMENT and "season=winter" in refused.details()

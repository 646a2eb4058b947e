"""Unary calls, error mapping, health and reflection against a real ``gridplace serve``."""

from __future__ import annotations

import asyncio
import re
from pathlib import Path
from typing import Any

import grpc
import numpy as np
import pytest
from grpc_health.v1 import health_pb2, health_pb2_grpc
from grpc_helpers import TOKEN, Served
from grpc_reflection.v1alpha import reflection_pb2, reflection_pb2_grpc

from service.errors import ConflictError, NotFoundError, UnavailableError
from service.grpc import messages
from service.grpc.gen import localization_pb2 as pb
from service.grpc.gen import localization_pb2_grpc as pb_grpc

pytestmark = pytest.mark.slow
ADMIN = (("authorization", f"Bearer {TOKEN}"),)


def run(served: Served, body: Any) -> Any:
    async def go() -> Any:
        async with grpc.aio.insecure_channel(served.target) as channel:
            return await body(channel)

    return asyncio.run(go())


def f32(x: np.ndarray) -> bytes:
    return np.ascontiguousarray(x, dtype="<f4").tobytes()


def call_error(served: Served, request: pb.LocalizeRequest) -> grpc.aio.AioRpcError:
    async def body(channel: grpc.aio.Channel) -> grpc.aio.AioRpcError:
        with pytest.raises(grpc.aio.AioRpcError) as err:
            await pb_grpc.LocalizationStub(channel).Localize(request)
        return err.value

    return run(served, body)  # type: ignore[no-any-return]


def test_localize_one_and_a_batch_match_the_artifact(served: Served) -> None:
    async def body(channel: grpc.aio.Channel) -> list[pb.LocalizeResponse]:
        stub = pb_grpc.LocalizationStub(channel)
        one = await stub.Localize(pb.LocalizeRequest(map="route", descriptor=f32(served.query[7])))
        many = await stub.Localize(pb.LocalizeRequest(map="route", descriptor=f32(served.query[:50]),
                                                      dimension=served.query.shape[1]))  # fmt: skip
        return [one, many]

    one, many = run(served, body)
    assert one.map == "route" and one.version == 1 and len(one.matches) == 1
    assert one.matches[0].index == served.oracle[7] and 0 < one.matches[0].confidence <= 1
    assert [m.index for m in many.matches] == served.oracle[:50].tolist()
    assert many.latency_ms > 0


def test_localize_an_image_with_the_stored_extractor(served: Served) -> None:
    async def body(channel: grpc.aio.Channel) -> list[int]:
        stub = pb_grpc.LocalizationStub(channel)
        return [(await stub.Localize(pb.LocalizeRequest(map="imgs", image=served.images[i])))
                .matches[0].index for i in (3, 40)]  # fmt: skip

    assert run(served, body) == [served.image_oracle[3], served.image_oracle[40]]


@pytest.mark.parametrize(
    ("request_", "status", "code"),
    [
        (pb.LocalizeRequest(map="nowhere", descriptor=f32(np.zeros(64))), "NOT_FOUND", "not_found"),
        (pb.LocalizeRequest(map="route", descriptor=f32(np.zeros(63))), "INVALID_ARGUMENT",
         "dimension_mismatch"),
        (pb.LocalizeRequest(map="route", descriptor=f32(np.zeros(64)), dimension=32),
         "INVALID_ARGUMENT", "dimension_mismatch"),
        (pb.LocalizeRequest(map="route", descriptor=b"\x00\x00\x80"), "INVALID_ARGUMENT",
         "invalid_input"),
        (pb.LocalizeRequest(map="route", descriptor=f32(np.full(64, np.nan))), "INVALID_ARGUMENT",
         "non_finite_input"),
        (pb.LocalizeRequest(map="route"), "INVALID_ARGUMENT", "empty_input"),
        (pb.LocalizeRequest(map="imgs", image=b"not an image"), "INVALID_ARGUMENT", None),
        (pb.LocalizeRequest(map="parked", descriptor=f32(np.zeros(64))), "FAILED_PRECONDITION",
         "conflict"),
        (pb.LocalizeRequest(map="route", image=b"\x89PNG"), "FAILED_PRECONDITION", "conflict"),
    ],
)
def test_errors_map_to_status_codes(served: Served, request_: pb.LocalizeRequest, status: str,
                                    code: str | None) -> None:  # fmt: skip
    err = call_error(served, request_)
    assert err.code() == getattr(grpc.StatusCode, status), err.details()
    assert err.details()
    trailing = dict(err.trailing_metadata() or ())
    assert code is None or trailing.get("gridplace-error") == code


def test_error_classes_carry_their_status() -> None:
    assert messages.status_code(UnavailableError("x")) == grpc.StatusCode.UNAVAILABLE
    assert messages.status_code(NotFoundError("x")) == grpc.StatusCode.NOT_FOUND
    assert messages.status_code(ConflictError("x")) == grpc.StatusCode.FAILED_PRECONDITION


def test_list_and_get_maps_are_admin_calls(served: Served) -> None:
    async def body(channel: grpc.aio.Channel) -> tuple[Any, ...]:
        stub = pb_grpc.LocalizationStub(channel)
        maps = await stub.ListMaps(pb.ListMapsRequest(), metadata=ADMIN)
        route = await stub.GetMap(pb.GetMapRequest(name="route"), metadata=ADMIN)
        parked = await stub.GetMap(pb.GetMapRequest(name="parked"), metadata=ADMIN)
        with pytest.raises(grpc.aio.AioRpcError) as anon:
            await stub.ListMaps(pb.ListMapsRequest())
        with pytest.raises(grpc.aio.AioRpcError) as anon_get:
            await stub.GetMap(pb.GetMapRequest(name="route"))
        with pytest.raises(grpc.aio.AioRpcError) as missing:
            await stub.GetMap(pb.GetMapRequest(name="nowhere"), metadata=ADMIN)
        return maps, route, parked, anon.value, anon_get.value, missing.value

    maps, route, parked, anon, anon_get, missing = run(served, body)
    assert {"route", "imgs", "parked", "swap"} <= {m.name for m in maps.maps}
    assert route.active_version == 1 and route.serving_version == 1
    assert route.active.n_frames == served.reference.shape[0] and route.active.n_features == 64
    assert route.active.paper_bytes > 0 and len(route.active.sha256) == 64
    assert not route.active.image_extractor and route.created_at.seconds > 0
    assert route.active.n_traversals == 1
    assert not parked.HasField("active_version") and list(parked.versions) == [1]
    assert anon.code() == anon_get.code() == grpc.StatusCode.UNAUTHENTICATED
    assert missing.code() == grpc.StatusCode.NOT_FOUND
    assert route.active.kind in _documented_kinds()


PROTO = Path(__file__).resolve().parents[2] / "protos/gridplace/v1/localization.proto"


def _documented_kinds() -> set[str]:
    line = next(ln for ln in PROTO.read_text().splitlines() if "string kind = 4;" in ln)
    return set(re.findall(r'"([a-z_]+)"', line))


def test_the_proto_says_what_the_server_does() -> None:
    from service.encoding import ChunkedPlaceEncoder, PhaseEncoder

    assert _documented_kinds() == {PhaseEncoder.kind, ChunkedPlaceEncoder.kind}
    lines = PROTO.read_text().splitlines()
    for rpc in ("ListMaps", "GetMap"):  # every admin RPC says so in its own comment
        at = next(i for i, ln in enumerate(lines) if f"rpc {rpc}(" in ln)
        comment = []
        for ln in reversed(lines[:at]):
            if not ln.strip().startswith("//"):
                break
            comment.append(ln)
        assert "Admin call" in " ".join(comment) and "Bearer" in " ".join(comment), rpc


def test_health_is_serving_once_ready(served: Served) -> None:
    # Another test of this package may have just activated a version on the shared server: health
    # is NOT_SERVING until it is loaded, so the check waits (bounded) for readiness to come back.
    async def body(channel: grpc.aio.Channel) -> list[int]:
        stub = health_pb2_grpc.HealthStub(channel)
        deadline = asyncio.get_running_loop().time() + 30
        while True:
            out = [(await stub.Check(health_pb2.HealthCheckRequest(service=service))).status
                   for service in ("", "gridplace.v1.Localization")]  # fmt: skip
            if out == [health_pb2.HealthCheckResponse.SERVING] * 2 or asyncio.get_running_loop().time() > deadline:
                return out
            await asyncio.sleep(0.1)

    assert run(served, body) == [health_pb2.HealthCheckResponse.SERVING] * 2


def test_reflection_lists_and_describes_the_service(served: Served) -> None:
    async def body(channel: grpc.aio.Channel) -> list[reflection_pb2.ServerReflectionResponse]:
        stub = reflection_pb2_grpc.ServerReflectionStub(channel)
        requests = [reflection_pb2.ServerReflectionRequest(list_services=""),
                    reflection_pb2.ServerReflectionRequest(
                        file_containing_symbol="gridplace.v1.Localization")]  # fmt: skip
        return [r async for r in stub.ServerReflectionInfo(iter(requests))]

    listed, described = run(served, body)
    names = {s.name for s in listed.list_services_response.service}
    assert {"gridplace.v1.Localization", "grpc.health.v1.Health"} <= names
    from google.protobuf import descriptor_pb2

    files = [descriptor_pb2.FileDescriptorProto.FromString(b)
             for b in described.file_descriptor_response.file_descriptor_proto]  # fmt: skip
    assert any(f.name == "gridplace/v1/localization.proto" and f.package == "gridplace.v1"
               for f in files)  # fmt: skip

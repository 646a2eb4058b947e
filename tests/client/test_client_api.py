"""Every :class:`GridplaceClient` method against a real ``gridplace serve`` (SYNTHETIC data)."""

from __future__ import annotations

import asyncio
import io
from pathlib import Path

import numpy as np
import pytest
from client_helpers import IMAGE_OPTIONS, TOKEN, D, N, images_zip, png, wait_serving

from service.api.process import ServerProcess, free_port
from service.client import (
    AsyncGridplaceClient,
    GridplaceClient,
    Job,
    RequestValidationError,
    ServerUnreachableError,
)
from service.errors import (
    ConflictError,
    DimensionMismatchError,
    EmptyInputError,
    GridplaceError,
    InvalidInputError,
    InvalidParameterError,
    NotFoundError,
    PayloadTooLargeError,
    UnauthorizedError,
)
from service.registry import Registry

pytestmark = pytest.mark.slow
Route = tuple[np.ndarray, np.ndarray]


def _oracle(data_dir: Path, name: str, version: int, X: np.ndarray) -> list[int]:
    """What the stored artifact answers in-process."""
    model = Registry(data_dir, cleanup_grace_s=None).load_model(name, version)
    return model.localize(np.atleast_2d(X)).index.tolist()  # type: ignore[no-any-return]


def test_health_ready_and_the_trained_map(gp: GridplaceClient, synth: Job) -> None:
    assert gp.health().status == "ok"
    ready = gp.ready()
    assert ready.ready and ready.loaded["synth"] == synth.version == 1
    maps = {m.name: m for m in gp.list_maps()}
    assert maps["synth"].active_version == 1 and maps["synth"].versions == [1]
    detail = gp.get_map("synth")
    assert detail.serving_version == 1 and detail.active is not None
    assert detail.active.n_frames == N and detail.active.n_features == D
    (v1,) = gp.list_versions("synth")
    assert v1.active and v1.params["trainer"] == "ridge" and v1.job_id == synth.id
    assert v1.footprint["actual_bytes"] > 0 and v1.extractor is None
    assert gp.get_version("synth", 1) == v1
    assert gp.get_job(synth.id) == synth


def test_localize_and_batch_agree_with_the_artifact(gp: GridplaceClient, synth: Job, route: Route,
                                                     data_dir: Path) -> None:  # fmt: skip
    Q = route[1][:30]
    want = _oracle(data_dir, "synth", 1, Q)
    one = gp.localize("synth", Q[0])
    assert (one.map, one.version, one.index) == ("synth", 1, want[0])
    assert 0.0 <= one.confidence <= 1.0 and one.latency_ms > 0
    assert gp.localize("synth", Q[1].tolist()).index == want[1]  # plain lists work too
    batch = gp.localize_batch("synth", Q)
    assert batch.n == 30 and batch.index == want and len(batch.confidence) == 30
    assert gp.localize_batch("synth", Q.astype(np.float64)).index == want  # converted to float32
    hits = np.abs(np.array(gp.localize_batch("synth", route[0]).index) - np.arange(N)) <= 3
    assert hits.mean() > 0.5  # the served model localizes its own route


def test_a_vehicle_gets_answers_adapted_to_its_earlier_queries(gp: GridplaceClient, synth: Job,
                                                               route: Route, data_dir: Path) -> None:  # fmt: skip
    from service.encoding.adaptation import adapt_drive
    from service.registry import Registry

    model = Registry(data_dir).load_model("synth", 1)
    Q = route[1][:20]
    want = model.localize(adapt_drive(model, Q.astype(np.float32).astype(np.float64))).index.tolist()
    got = [gp.localize("synth", q, vehicle_id="client-van") for q in Q]
    assert all(g.adapted for g in got) and [g.index for g in got] == want
    plain = gp.localize("synth", Q[3], vehicle_id="client-van", adaptation=False)
    assert not plain.adapted and plain.index == _oracle(data_dir, "synth", 1, Q[3:4])[0]


def test_upload_from_a_file_activate_and_delete(gp: GridplaceClient, synth: Job, route: Route,
                                                tmp_path: Path) -> None:  # fmt: skip
    path = tmp_path / "route.npy"
    np.save(path, route[0][::-1].copy(), allow_pickle=False)  # the route driven backwards
    job = gp.upload_route("synth", path, trainer="ridge", n_patterns=2, periods=[20, 15])
    assert job.map == "synth" and job.state in ("queued", "running", "succeeded")
    job = gp.wait_for_job(job.id, timeout=90, poll_interval=0.05)
    assert job.state == "succeeded" and job.version == 2
    assert gp.get_map("synth").active_version == 1  # a later version waits for activation
    assert gp.activate("synth", 2).active
    wait_serving(gp, "synth", 2)
    assert gp.list_versions("synth")[1].params["periods"] == [20, 15]
    with pytest.raises(ConflictError):
        gp.delete_version("synth", 2)  # the active version
    gp.activate("synth", 1)
    wait_serving(gp, "synth", 1)
    gp.delete_version("synth", 2)
    assert [v.version for v in gp.list_versions("synth")] == [1]
    with pytest.raises(NotFoundError):
        gp.get_version("synth", 2)


def test_image_route_and_image_queries(gp: GridplaceClient) -> None:
    job = gp.upload_route(
        "imgs", images_zip(24), IMAGE_OPTIONS, filename="frames.zip", trainer="ridge"
    )
    job = gp.wait_for_job(job.id, timeout=90, poll_interval=0.05)
    assert job.state == "succeeded", job.error
    wait_serving(gp, "imgs", 1)
    active = gp.get_map("imgs").active
    assert active is not None and active.extractor is not None
    assert active.extractor["kind"] == "patchnorm" and active.params["trainer"] == "ridge"
    one = gp.localize("imgs", image=png(3))
    assert one.map == "imgs" and 0 <= one.index < 24
    many = gp.localize_images("imgs", [png(3), png(7)])
    assert many.n == 2 and many.index[0] == one.index
    gp.deactivate("imgs")
    with pytest.raises(ConflictError) as exc:  # out of service: 409
        gp.localize("imgs", image=png(3))
    assert exc.value.details["http_status"] == 409


def test_server_errors_come_back_as_the_one_hierarchy(gp: GridplaceClient, synth: Job,
                                                      route: Route, server: ServerProcess) -> None:  # fmt: skip
    q = route[1][0]
    with pytest.raises(NotFoundError, match="nope"):
        gp.localize("nope", q)
    with pytest.raises(NotFoundError):
        gp.get_job("0" * 32)
    with pytest.raises(DimensionMismatchError) as dim:
        gp.localize("synth", q[:10])
    assert dim.value.code == "dimension_mismatch" and dim.value.http_status == 400
    with pytest.raises(DimensionMismatchError):
        gp.localize_batch("synth", route[1][:3, :10])
    nan = q.copy()
    nan[3] = np.nan
    with pytest.raises(InvalidInputError) as bad:
        gp.localize("synth", nan)
    assert bad.value.code == "non_finite_input"
    with pytest.raises(PayloadTooLargeError):  # GRIDPLACE_MAX_UPLOAD_MB=1
        gp.upload_route("big", np.zeros((5000, 64), np.float32), trainer="ridge")
    pickled = io.BytesIO()
    np.save(pickled, np.array([{"a": 1}], dtype=object), allow_pickle=True)
    with pytest.raises(InvalidInputError) as unsafe:  # pickled arrays are refused by the server
        gp.upload_route("pickled", pickled.getvalue(), filename="route.npy", trainer="ridge")
    assert unsafe.value.code == "unsafe_or_malformed_file"
    with GridplaceClient(server.url, token="wrong") as other:
        with pytest.raises(UnauthorizedError, match="invalid admin token"):
            other.list_maps()
        assert other.localize("synth", q).map == "synth"  # localize needs no token
    with GridplaceClient(server.url, token="") as anonymous, pytest.raises(UnauthorizedError):
        anonymous.get_map("synth")
    assert gp.list_versions("synth")  # nothing above broke the map


def test_client_side_validation_fails_before_sending(gp: GridplaceClient, tmp_path: Path) -> None:
    with pytest.raises(InvalidParameterError, match="trainer"):
        gp.upload_route("synth", np.zeros((10, 4)), trainer="magic")
    with pytest.raises(InvalidParameterError, match="not_an_option"):
        gp.upload_route("synth", np.zeros((10, 4)), not_an_option=1)
    with pytest.raises(InvalidInputError, match="not found"):
        gp.upload_route("synth", tmp_path / "missing.npy")
    with pytest.raises(EmptyInputError):
        gp.localize_batch("synth", np.zeros((0, 4)))
    with pytest.raises(InvalidInputError, match="exactly one"):
        gp.localize("synth")
    with pytest.raises(InvalidInputError, match="localize_batch"):
        gp.localize("synth", np.zeros((2, 4)))


def test_request_validation_is_a_422(server: ServerProcess) -> None:
    import httpx

    from service.client import error_from_response

    r = httpx.post(server.url + "/v1/localize", json={"map": "synth"})
    err = error_from_response(r)
    assert isinstance(err, RequestValidationError) and err.http_status == 422
    assert "exactly one" in err.message


def test_unreachable_server_is_a_clear_unavailable_error() -> None:
    with (
        GridplaceClient(f"http://127.0.0.1:{free_port()}", timeout=2) as gone,
        pytest.raises(ServerUnreachableError, match="cannot reach the gridplace server") as exc,
    ):
        gone.health()
    assert exc.value.code == "server_unreachable" and exc.value.http_status == 503


def test_async_client(
    server: ServerProcess, synth: Job, route: Route, data_dir: Path, tmp_path: Path
) -> None:
    Q = route[1][:8]
    want = _oracle(data_dir, "synth", 1, Q)
    path = tmp_path / "async-route.npy"
    np.save(path, route[0][:120], allow_pickle=False)

    async def main() -> None:
        async with AsyncGridplaceClient(server.url, token=TOKEN) as agp:
            assert (await agp.health()).status == "ok"
            hits = await asyncio.gather(*(agp.localize("synth", q) for q in Q))
            assert [h.index for h in hits] == want
            assert (await agp.localize_batch("synth", Q)).index == want
            assert "synth" in [m.name for m in await agp.list_maps()]
            assert (await agp.get_job(synth.id)).version == 1
            with pytest.raises(NotFoundError):
                await agp.list_versions("nope")
            with pytest.raises(GridplaceError):
                await agp.activate("synth", 99)
            job = await agp.upload_route("async", path, trainer="ridge", idempotency_key="a-1")
            done = await agp.wait_for_job(job.id, timeout=90, poll_interval=0.05)
            assert done.state == "succeeded" and done.version == 1
            assert (await agp.get_map("async")).active_version == 1

    asyncio.run(main())

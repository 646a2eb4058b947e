"""Public requests in flight are bounded server-wide (``GRIDPLACE_MAX_PUBLIC_REQUESTS``,
``GRIDPLACE_MAX_PUBLIC_BODIES_MB``), against a real ``gridplace serve`` with small limits.

gRPC ``Localize`` calls lease from the same budget. Before: every public body being received was held whole by the server for as long as its
caller took to send the last byte, and their number was bounded by nothing: 24 slow 4 MB
bodies held ≈ 96 MB. Callers here are raw sockets that send a body all but its last byte.

Data is SYNTHETIC (a smooth random-process route, N = 300, d = 64, ridge)."""

from __future__ import annotations

import io
import socket
import time
from collections.abc import Iterator
from pathlib import Path

import grpc
import httpx
import numpy as np
import psutil
import pytest

from service.api.process import ServerProcess, free_port
from service.encoding import ModelParams, build_model
from service.encoding.synthetic import smooth_route
from service.grpc.gen import localization_pb2 as pb
from service.grpc.gen import localization_pb2_grpc as pb_grpc
from service.registry import Registry

pytestmark = pytest.mark.slow
TOKEN = "inflight-admin-token"
AUTH = {"Authorization": f"Bearer {TOKEN}"}
N, D = 300, 64
MIB = 2**20
MAX_REQUESTS, BODIES_MB, BODY_MB = 6, 8, 4
ENV = {"GRIDPLACE_ADMIN_TOKEN": TOKEN, "GRIDPLACE_MAX_UPLOAD_MB": "16",
       "GRIDPLACE_MAX_PUBLIC_BODY_MB": str(BODY_MB), "GRIDPLACE_MAX_PUBLIC_BODIES_MB": str(BODIES_MB),
       "GRIDPLACE_MAX_PUBLIC_REQUESTS": str(MAX_REQUESTS), "GRIDPLACE_TRAIN_WORKERS": "1"}  # fmt: skip


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[ServerProcess]:
    data: Path = tmp_path_factory.mktemp("inflight")
    params = ModelParams.parse(trainer="ridge", n_patterns=2)
    Registry(data).publish("route", build_model(params).fit(smooth_route(N, D, seed=3).reference),
                           params=params.model_dump(mode="json"), extractor=None, metrics={},
                           job_id=None)  # fmt: skip
    with ServerProcess(data, env={**ENV, "GRIDPLACE_GRPC_PORT": str(free_port())}) as srv:
        srv.wait_ready(60)
        yield srv


class SlowBody:
    """A raw HTTP/1.1 request whose body is sent all but its last byte, then held."""

    def __init__(self, url: str, length: int, chunked: bool = False) -> None:
        host, port = url.removeprefix("http://").split(":")
        self.sock = socket.create_connection((host, int(port)), timeout=10)
        framing = b"Transfer-Encoding: chunked" if chunked else b"Content-Length: %d" % length
        self.sock.sendall(b"POST /v1/localize/batch HTTP/1.1\r\nHost: x\r\n"
                          b"Content-Type: application/json\r\n" + framing + b"\r\n\r\n")  # fmt: skip
        self.length, self.chunked = length, chunked

    def answered(self, wait_s: float) -> str | None:
        """The server's answer if one comes within ``wait_s`` (a refusal before the body)."""
        self.sock.settimeout(wait_s)
        data = b""
        try:
            while True:
                part = self.sock.recv(65536)
                data += part
                head, sep, body = data.partition(b"\r\n\r\n")
                length = next((int(line.split(b":")[1]) for line in head.lower().split(b"\r\n")
                               if line.startswith(b"content-length:")), 0)  # fmt: skip
                if not part or (sep and len(body) >= length):
                    break
                self.sock.settimeout(5)  # the rest of an answer that has begun
        except (TimeoutError, ConnectionError):
            pass
        return data.decode(errors="replace") or None

    def send_all_but_the_last_byte(self) -> None:
        body = b'{"map": "route", "descriptors": [[' + b" " * (self.length - 40)
        self.sock.settimeout(30)
        if self.chunked:
            for i in range(0, len(body), 64 * 1024):
                part = body[i : i + 64 * 1024]
                self.sock.sendall(b"%x\r\n%s\r\n" % (len(part), part))
        else:
            self.sock.sendall(body[: self.length - 1])

    def close(self) -> None:
        self.sock.close()


def _rss(srv: ServerProcess) -> int:
    assert srv.proc is not None
    return int(psutil.Process(srv.proc.pid).memory_info().rss)


def _ok(srv: ServerProcess) -> int:
    return httpx.post(f"{srv.url}/v1/localize/batch", timeout=30,
                      json={"map": "route", "descriptors": np.zeros((2, D)).tolist()}).status_code  # fmt: skip


def _settle(srv: ServerProcess) -> None:
    """Until the leases of closed callers are back (their disconnects reach the app)."""
    deadline = time.monotonic() + 10
    while _ok(srv) != 200 and time.monotonic() < deadline:
        time.sleep(0.1)


def test_slow_bodies_beyond_the_byte_budget_are_refused_and_memory_stays_bounded(
    server: ServerProcess,
) -> None:
    _settle(server)
    before = _rss(server)
    callers = [SlowBody(server.url, 4_000_000) for _ in range(24)]  # 96 MB of bodies
    try:
        held, refused = [], []
        for caller in callers:
            answer = caller.answered(0.5)
            if answer is None:
                caller.send_all_but_the_last_byte()
                held.append(caller)
            else:
                refused.append(answer)
        peak = _rss(server)
        assert len(held) == BODIES_MB * MIB // 4_000_000 == 2, (len(held), refused[:1])
        assert all(a.startswith("HTTP/1.1 503") for a in refused), refused[:1]
        assert all("GRIDPLACE_MAX_PUBLIC_BODIES_MB" in a and "retry-after: 1" in a.lower()
                   for a in refused)  # fmt: skip
        assert peak - before < 40 * MIB, (before, peak)  # 2 × 4 MB held, not 24 × 4 MB
        # while the budget is taken: health answers, an admin upload larger than what is left
        # of it is accepted (its own limit), a chunked public body is refused as it arrives
        assert httpx.get(f"{server.url}/healthz", timeout=10).status_code == 200
        buf = io.BytesIO()
        np.save(buf, smooth_route(5000, 256, seed=4).reference.astype(np.float32))
        upload = httpx.post(f"{server.url}/v1/maps/uploaded/routes", headers=AUTH, timeout=60,
                            files={"file": ("r.npy", buf.getvalue())}, data={"trainer": "ridge"})  # fmt: skip
        assert upload.status_code == 202, upload.text
        chunked = SlowBody(server.url, 1_000_000, chunked=True)
        try:
            chunked.send_all_but_the_last_byte()
        except ConnectionError:
            pass  # the server answered and closed while the body was still coming
        answer = chunked.answered(5) or ""
        chunked.close()
        assert answer.startswith("HTTP/1.1 503") and "GRIDPLACE_MAX_PUBLIC_BODIES_MB" in answer
    finally:
        for caller in callers:
            caller.close()
    _settle(server)
    assert _ok(server) == 200  # what the held callers reserved is given back


def test_requests_beyond_the_count_are_refused_and_others_answered_after(
    server: ServerProcess,
) -> None:
    _settle(server)
    callers = [SlowBody(server.url, 1000) for _ in range(MAX_REQUESTS)]
    try:
        for caller in callers:
            assert caller.answered(0.3) is None
            caller.send_all_but_the_last_byte()
        r = httpx.post(f"{server.url}/v1/localize", timeout=10,
                       json={"map": "route", "descriptor": [0.0] * D})  # fmt: skip
        assert r.status_code == 503, r.text
        assert r.json()["error"] == "capacity_exhausted"
        assert f"GRIDPLACE_MAX_PUBLIC_REQUESTS={MAX_REQUESTS}" in r.json()["message"]
        assert r.headers["retry-after"] == "1"
        assert httpx.get(f"{server.url}/readyz", timeout=10).status_code == 200
    finally:
        for caller in callers:
            caller.close()
    _settle(server)
    answers = [_ok(server) for _ in range(2 * MAX_REQUESTS)]
    assert answers == [200] * (2 * MAX_REQUESTS)


def test_a_grpc_localize_beyond_the_budget_is_resource_exhausted(server: ServerProcess) -> None:
    _settle(server)
    request = pb.LocalizeRequest(map="route", descriptor=np.zeros(D, "<f4").tobytes())
    callers = [SlowBody(server.url, 1000) for _ in range(MAX_REQUESTS)]
    with grpc.insecure_channel(f"127.0.0.1:{server.env['GRIDPLACE_GRPC_PORT']}") as channel:
        stub = pb_grpc.LocalizationStub(channel)
        try:
            for caller in callers:
                caller.send_all_but_the_last_byte()
            time.sleep(0.3)
            with pytest.raises(grpc.RpcError) as refused:
                stub.Localize(request, timeout=10)
            assert refused.value.code() == grpc.StatusCode.RESOURCE_EXHAUSTED
            assert f"GRIDPLACE_MAX_PUBLIC_REQUESTS={MAX_REQUESTS}" in (refused.value.details() or "")
        finally:
            for caller in callers:
                caller.close()
        _settle(server)
        assert len(stub.Localize(request, timeout=10).matches) == 1

"""The worst load an unauthenticated caller can put on a server at once, one generator per
kind (``gridplace bench public-rss`` runs them together against a real ``gridplace serve``).

* :func:`fill_rest_vehicles`: REST vehicles, one new ``vehicle_id`` per query, until the store
  holds as many as its settings allow (its least recently seen are then forgotten).
* :class:`HeldStreams`: every gRPC stream the server allows, each driving as many filtered
  vehicles as it will take (up to the per-stream 1,024), held open.
* :class:`Loops` of :func:`drive_request`: drives with the dearest filter grid at the work
  budget; of :func:`batch_request`: JSON batches at the body limit (the costliest body to parse).
* :class:`SlowBodies`: requests whose body never ends, holding places in the public budget.

Refusals the settings make (503 ``capacity_exhausted``, 413 beyond the work budget, stream
frames answered ``RESOURCE_EXHAUSTED``) are counted, not errors: they are the bound working.
"""

from __future__ import annotations

import asyncio
import base64
import json
import socket
import threading
import time
from collections import Counter
from collections.abc import AsyncIterator

import httpx
import numpy as np

from service.encoding.sequence import SequenceConfig

#: the dearest sequence filter the options allow: 2 × 64 speeds + a stopped state per direction
WORST_FILTER = {"min_speed": 0, "max_speed": 50, "speed_step": 50 / 63, "reverse": True,
                "stop_probability": 0.1}  # fmt: skip
WORST_STATES = SequenceConfig.parse(**WORST_FILTER).n_states
MAX_VEHICLES_PER_STREAM = 1024


def fill_rest_vehicles(url: str, name: str, queries: np.ndarray, n: int, threads: int = 4) -> Counter[str]:
    """``n`` REST queries, each a new vehicle (a new id, no key): statuses counted."""
    statuses: Counter[str] = Counter()
    lock = threading.Lock()

    def work(start: int) -> None:
        with httpx.Client(base_url=url, timeout=60) as client:
            for i in range(start, n, threads):
                row = queries[i % len(queries)].astype("<f4").tobytes()
                r = client.post("/v1/localize", json={
                    "map": name, "vehicle_id": f"rest-{i}",
                    "descriptor_b64": base64.b64encode(row).decode()})  # fmt: skip
                with lock:
                    statuses[str(r.status_code)] += 1

    pool = [threading.Thread(target=work, args=(t,)) for t in range(threads)]
    for t in pool:
        t.start()
    for t in pool:
        t.join()
    return statuses


class HeldStreams:
    """``n`` gRPC streams on their own thread and loop; each sends filtered vehicles (one
    frame each) until one is refused or it has sent 1,024, then stays open until
    :meth:`close`."""

    def __init__(self, target: str, name: str, queries: np.ndarray, n: int, window: int = 16) -> None:
        self.target, self.name, self.queries, self.n, self.window = target, name, queries, n, window
        self.answers: Counter[str] = Counter()
        self.opened = threading.Event()
        self._loop = asyncio.new_event_loop()
        self._release: asyncio.Event | None = None
        self._thread = threading.Thread(target=self._loop.run_until_complete, args=(self._run(),),
                                        daemon=True)  # fmt: skip

    def start(self) -> HeldStreams:
        self._thread.start()
        return self

    def wait_filled(self, timeout_s: float) -> bool:
        return self.opened.wait(timeout_s)

    def close(self) -> None:
        if self._release is not None:
            self._loop.call_soon_threadsafe(self._release.set)
        self._thread.join(120)

    async def _run(self) -> None:
        import grpc

        from service.grpc.gen import localization_pb2_grpc as pb_grpc

        self._release = asyncio.Event()
        async with grpc.aio.insecure_channel(self.target) as channel:
            stub = pb_grpc.LocalizationStub(channel)
            filled = [asyncio.Event() for _ in range(self.n)]
            tasks = [asyncio.create_task(self._stream(stub, s, filled[s])) for s in range(self.n)]
            await asyncio.gather(*(e.wait() for e in filled))
            self.opened.set()
            await asyncio.gather(*tasks)

    async def _stream(self, stub: object, s: int, filled: asyncio.Event) -> None:
        import grpc

        from service.grpc.gen import localization_pb2 as pb

        assert self._release is not None
        queue: asyncio.Queue[object] = asyncio.Queue()

        async def feed() -> AsyncIterator[object]:
            while (item := await queue.get()) is not None:
                yield item

        call = stub.LocalizeStream(feed())  # type: ignore[attr-defined]
        try:
            refused, v = False, 0
            while not refused and v < MAX_VEHICLES_PER_STREAM:
                sent = min(self.window, MAX_VEHICLES_PER_STREAM - v)
                for k in range(v, v + sent):
                    row = self.queries[(s * 997 + k) % len(self.queries)]
                    await queue.put(pb.StreamRequest(vehicle_id=f"s{s}-v{k}", sequence=k,
                                                     map=self.name, sequence_filter=True,
                                                     descriptor=row.astype("<f4").tobytes()))  # fmt: skip
                for _ in range(sent):
                    answer = await call.read()
                    code = answer.error.status if answer.HasField("error") else "OK"
                    self.answers[code] += 1
                    refused |= code == "RESOURCE_EXHAUSTED"
                v += sent
        except grpc.aio.AioRpcError as exc:
            self.answers[f"stream {exc.code().name}"] += 1
        finally:
            filled.set()
        await self._release.wait()
        await queue.put(None)
        try:
            while await call.read() is not grpc.aio.EOF:
                pass
        except grpc.aio.AioRpcError:
            pass


def _post_until(stop: threading.Event, statuses: Counter[str], lock: threading.Lock,
                base_url: str, **request: object) -> None:  # fmt: skip
    with httpx.Client(base_url=base_url, timeout=1800) as client:  # a loaded machine is slow
        while not stop.is_set():
            try:
                r = client.post(**request)  # type: ignore[arg-type]
                status = str(r.status_code)
            except httpx.TransportError as exc:
                status = type(exc).__name__
            with lock:
                statuses[status] += 1
            if status == "503":
                time.sleep(0.05)  # Retry-After says 1 s; the bench keeps the budget full


def drive_request(name: str, queries: np.ndarray, frames: int) -> dict[str, object]:
    """A binary drive of ``frames`` frames with the dearest filter grid."""
    return {"url": "/v1/localize/sequence", "params": {"map": name, **WORST_FILTER},
            "content": queries[:frames].astype("<f4").tobytes(),
            "headers": {"Content-Type": "application/octet-stream"}}  # fmt: skip


def batch_request(name: str, queries: np.ndarray, body_limit: int) -> dict[str, object]:
    """A JSON batch of as many rows as fit the body limit (rows repeated from ``queries``)."""
    rows64 = queries.astype(np.float64)
    rows = max(1, (body_limit - 1024) // (len(json.dumps(rows64[0].tolist())) + 2))
    while True:
        body = json.dumps({"map": name, "descriptors": np.resize(rows64, (rows, rows64.shape[1])).tolist()})
        if len(body) <= body_limit or rows == 1:
            break
        rows = rows * 9 // 10
    return {"url": "/v1/localize/batch", "content": body.encode(),
            "headers": {"Content-Type": "application/json"}}


class Loops:
    """``n`` threads each posting one request again and again until :meth:`stop`."""

    def __init__(self, url: str, n: int, request: dict[str, object]) -> None:
        self.statuses: Counter[str] = Counter()
        self._stop, self._lock = threading.Event(), threading.Lock()
        self._threads = [threading.Thread(target=_post_until, daemon=True,
                                          args=(self._stop, self.statuses, self._lock, url),
                                          kwargs=request) for _ in range(n)]  # fmt: skip

    def start(self) -> Loops:
        for t in self._threads:
            t.start()
        return self

    def stop(self) -> Counter[str]:
        self._stop.set()
        for t in self._threads:
            t.join(600)
        return self.statuses


class SlowBodies:
    """``n`` raw requests that declare a small body and never finish it."""

    def __init__(self, url: str, n: int, declared: int = 1024) -> None:
        host, port = url.removeprefix("http://").split(":")
        self._socks = [socket.create_connection((host, int(port)), timeout=10) for _ in range(n)]
        for sock in self._socks:
            sock.sendall(b"POST /v1/localize/batch HTTP/1.1\r\nHost: bench\r\nContent-Type: "
                         b"application/json\r\nContent-Length: %d\r\n\r\n{" % declared)  # fmt: skip

    def tally(self) -> tuple[int, int]:
        """(held, refused): a refused request has its 503 by now (it comes before the body,
        however late a loaded server sends it); a held one is still waiting for its body."""
        held = refused = 0
        for sock in self._socks:
            sock.setblocking(False)
            try:
                answered = bool(sock.recv(64))
            except BlockingIOError:
                answered = False
            except OSError:
                answered = True  # reset after its answer
            refused += answered
            held += not answered
        return held, refused

    def close(self) -> None:
        for sock in self._socks:
            sock.close()

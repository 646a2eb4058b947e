"""``AsyncGridplaceClient``: :class:`~service.client.GridplaceClient` for asyncio code.

The same calls (built once in :mod:`service.client.calls`), awaited::

    async with AsyncGridplaceClient(url) as gp:
        hits = await asyncio.gather(*(gp.localize("nordland", q) for q in queries))
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import Sequence
from types import TracebackType
from typing import Any, Self, TypeVar

import httpx
import numpy as np
from numpy.typing import ArrayLike

from service.client import calls
from service.client.calls import Call, ImageSource, RouteSource
from service.client.client import JobCallback, TimeoutTypes, answer, auth_headers, resolve
from service.client.errors import JobTimeoutError, transport_error
from service.client.vehicle_keys import VehicleKeys
from service.wire import (
    BatchLocalization,
    Health,
    Job,
    JobPage,
    Localization,
    MapDetail,
    MapSummary,
    Readiness,
    SequenceLocalization,
    TrainingOptions,
    Version,
)

T = TypeVar("T")


class AsyncGridplaceClient:
    """Same arguments and methods as :class:`~service.client.GridplaceClient`, awaited."""

    def __init__(
        self,
        base_url: str | None = None,
        *,
        token: str | None = None,
        timeout: TimeoutTypes = 30.0,
        upload_timeout: TimeoutTypes = 600.0,
        transport: httpx.AsyncBaseTransport | None = None,
        headers: dict[str, str] | None = None,
    ) -> None:
        self.base_url, self.token = resolve(base_url, token)
        self.upload_timeout = upload_timeout
        self._keys = VehicleKeys()  # the server's vehicle_key of each vehicle, per map
        self._http = httpx.AsyncClient(base_url=self.base_url, timeout=timeout, transport=transport,
                                       headers={"User-Agent": "gridplace-client", **(headers or {})})  # fmt: skip

    async def _send(self, call: Call[T], timeout: Any = httpx.USE_CLIENT_DEFAULT) -> T:
        kwargs = {**call.kwargs, "headers": auth_headers(call, self.token)}
        try:
            response = await self._http.request(call.method, call.path, timeout=timeout, **kwargs)
        except httpx.TransportError as exc:
            raise transport_error(exc, self.base_url) from exc
        finally:
            call.close()
        return answer(call, response)

    async def aclose(self) -> None:
        await self._http.aclose()

    async def __aenter__(self) -> Self:
        return self

    async def __aexit__(self, et: type[BaseException] | None, e: BaseException | None,
                        tb: TracebackType | None) -> None:  # fmt: skip
        await self.aclose()

    async def health(self) -> Health:
        return await self._send(calls.health())

    async def ready(self) -> Readiness:
        return await self._send(calls.ready())

    async def localize(self, map: str, descriptor: ArrayLike | None = None, *,
                       image: ImageSource | None = None, vehicle_id: str | None = None,
                       adaptation: bool | None = None, vehicle_key: str | None = None,
                       reset: bool | None = None, condition: str | None = None) -> Localization:  # fmt: skip
        """:meth:`GridplaceClient.localize` (vehicle keys remembered the same way)."""
        key = self._keys.key(map, vehicle_id, vehicle_key)
        answer = await self._send(calls.localize(map, descriptor, image, vehicle_id, adaptation,
                                                 key, reset, condition))  # fmt: skip
        self._keys.remember(map, vehicle_id, answer.vehicle_key)
        return answer

    async def localize_batch(self, map: str, descriptors: ArrayLike,
                             condition: str | None = None) -> BatchLocalization:  # fmt: skip
        return await self._send(calls.localize_batch(map, descriptors, condition))

    async def localize_images(self, map: str, images: Sequence[ImageSource],
                              condition: str | None = None) -> BatchLocalization:  # fmt: skip
        return await self._send(calls.localize_images(map, images, condition))

    async def localize_sequence(self, map: str, descriptors: ArrayLike, *,
                                adaptation: bool | None = None,
                                odometry: Sequence[float | None] | None = None,
                                condition: str | None = None,
                                **filter_params: Any) -> SequenceLocalization:  # fmt: skip
        return await self._send(calls.localize_sequence(map, descriptors, filter_params,
                                                        adaptation, odometry, condition))  # fmt: skip

    async def upload_route(self, map: str, route: RouteSource | Sequence[RouteSource],
                           options: TrainingOptions | None = None, *,
                           idempotency_key: str | None = None, filename: str | None = None,
                           places: Sequence[RouteSource] | None = None,
                           **params: Any) -> Job:  # fmt: skip
        """As :meth:`GridplaceClient.upload_route` (several traversals, ``places``)."""
        opts = calls.options_of(options, params)
        if isinstance(route, list | tuple):  # several traversals: each file read off the loop
            routes = [await self._read(r, None) for r in route]
            sent: RouteSource | list[RouteSource] = [body for body, _ in routes]
            names: list[str | None] | None = [name for _, name in routes]
        else:
            sent, filename = await self._read(route, filename)
            names = None
        index = None if places is None else [(await self._read(p, None))[0] for p in places]
        call = calls.upload_route(map, sent, opts, idempotency_key, filename, index, names)
        return await self._send(call, timeout=self.upload_timeout)

    async def append_traversals(
        self, map: str, version: int, traversals: RouteSource | Sequence[RouteSource], *,
        places: Sequence[RouteSource] | None = None, tags: Sequence[str] = (),
        extend: bool = False, whiten: bool | None = None, activate: bool = False,
    ) -> Version:  # fmt: skip
        """As :meth:`GridplaceClient.append_traversals` (files read off the event loop)."""
        opts = calls.append_options(tags, extend, whiten, activate)
        many = isinstance(traversals, list | tuple)
        sent = [(await self._read(t, None))[0] for t in (traversals if many else [traversals])]
        index = None if places is None else [(await self._read(p, None))[0] for p in places]
        call = calls.append_traversals(map, version, sent if many else sent[0], opts, index)
        return await self._send(call, timeout=self.upload_timeout)

    @staticmethod
    async def _read(
        source: RouteSource, filename: str | None
    ) -> tuple[bytes | np.ndarray, str | None]:
        """Bytes (or the array) of an upload part, files read off the event loop."""
        if isinstance(source, bytes | np.ndarray):
            return source, filename
        return await asyncio.to_thread(calls.read_route_file, source, filename)

    async def get_job(self, job_id: str) -> Job:
        return await self._send(calls.get_job(job_id))

    async def list_jobs(self, map: str | None = None, states: Sequence[str] | None = None,
                        limit: int = 50, cursor: str | None = None) -> JobPage:  # fmt: skip
        """One page of training jobs, newest first (``next_cursor`` fetches the next)."""
        return await self._send(calls.list_jobs(map, states, limit, cursor))

    async def wait_for_job(self, job_id: str, timeout: float = 600.0, poll_interval: float = 0.25,
                           on_update: JobCallback | None = None) -> Job:  # fmt: skip
        deadline = time.monotonic() + timeout
        while True:
            job = await self.get_job(job_id)
            if on_update is not None:
                on_update(job)
            if job.done:
                return job
            if time.monotonic() >= deadline:
                raise JobTimeoutError(f"job {job_id} still {job.state} ({job.stage}) after {timeout:.0f}s",
                                      job_id=job_id)  # fmt: skip
            await asyncio.sleep(poll_interval)

    async def list_maps(self) -> list[MapSummary]:
        return await self._send(calls.list_maps())

    async def get_map(self, name: str) -> MapDetail:
        return await self._send(calls.get_map(name))

    async def list_versions(self, name: str) -> list[Version]:
        return await self._send(calls.list_versions(name))

    async def get_version(self, name: str, version: int) -> Version:
        return await self._send(calls.get_version(name, version))

    async def activate(self, name: str, version: int) -> Version:
        return await self._send(calls.activate(name, version))

    async def deactivate(self, name: str) -> MapSummary:
        return await self._send(calls.deactivate(name))

    async def delete_version(self, name: str, version: int) -> None:
        await self._send(calls.delete_version(name, version))

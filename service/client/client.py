"""``GridplaceClient``: the REST API of a gridplace server as typed Python calls.

::

    from service.client import GridplaceClient

    with GridplaceClient("http://127.0.0.1:8080", token=admin_token) as gp:
        job = gp.upload_route("nordland", "ref.npy", trainer="ridge", idempotency_key="nl-1")
        job = gp.wait_for_job(job.id, timeout=600)
        hit = gp.localize("nordland", query_descriptor)      # .index, .confidence, .version
        batch = gp.localize_batch("nordland", queries)        # one binary float32 request

Every failure raises a class of :mod:`service.errors` (see :mod:`service.client.errors`).
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable, Sequence
from types import TracebackType
from typing import Any, Self, TypeVar

import httpx
from numpy.typing import ArrayLike

from service.client import calls
from service.client.calls import DEFAULT_URL, Call, ImageSource, RouteSource
from service.client.errors import JobTimeoutError, error_from_response, transport_error
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
TimeoutTypes = float | httpx.Timeout | None
JobCallback = Callable[[Job], None]


def resolve(base_url: str | None, token: str | None) -> tuple[str, str | None]:
    """Explicit arguments, else ``GRIDPLACE_URL`` / ``GRIDPLACE_ADMIN_TOKEN``, else defaults."""
    url = (base_url or os.environ.get("GRIDPLACE_URL") or DEFAULT_URL).rstrip("/")
    if "://" not in url:
        url = f"http://{url}"
    return url, token if token is not None else (os.environ.get("GRIDPLACE_ADMIN_TOKEN") or None)


def auth_headers(call: Call[Any], token: str | None) -> dict[str, str]:
    headers = dict(call.kwargs.get("headers") or {})
    if call.admin and token:
        headers["Authorization"] = f"Bearer {token}"
    return headers


def answer(call: Call[T], response: httpx.Response) -> T:
    if response.is_success or response.status_code in call.also_ok:
        return call.read(response)
    raise error_from_response(response)


class GridplaceClient:
    """A synchronous client (thread-safe; reuses connections). Use as a context manager or
    call :meth:`close`.

    ``base_url`` defaults to ``GRIDPLACE_URL`` (else ``http://127.0.0.1:8080``), ``token`` (the
    admin bearer token, sent on admin calls only) to ``GRIDPLACE_ADMIN_TOKEN``. ``timeout`` is
    per request; uploads use ``upload_timeout``."""

    def __init__(
        self,
        base_url: str | None = None,
        *,
        token: str | None = None,
        timeout: TimeoutTypes = 30.0,
        upload_timeout: TimeoutTypes = 600.0,
        transport: httpx.BaseTransport | None = None,
        headers: dict[str, str] | None = None,
    ) -> None:
        self.base_url, self.token = resolve(base_url, token)
        self.upload_timeout = upload_timeout
        self._keys = VehicleKeys()  # the server's vehicle_key of each vehicle, per map
        self._http = httpx.Client(base_url=self.base_url, timeout=timeout, transport=transport,
                                  headers={"User-Agent": "gridplace-client", **(headers or {})})  # fmt: skip

    # -- plumbing ---------------------------------------------------------------------------
    def _send(self, call: Call[T], timeout: Any = httpx.USE_CLIENT_DEFAULT) -> T:
        kwargs = {**call.kwargs, "headers": auth_headers(call, self.token)}
        try:
            response = self._http.request(call.method, call.path, timeout=timeout, **kwargs)
        except httpx.TransportError as exc:
            raise transport_error(exc, self.base_url) from exc
        finally:
            call.close()
        return answer(call, response)

    def close(self) -> None:
        self._http.close()

    def __enter__(self) -> Self:
        return self

    def __exit__(self, et: type[BaseException] | None, e: BaseException | None,
                 tb: TracebackType | None) -> None:  # fmt: skip
        self.close()

    # -- health -----------------------------------------------------------------------------
    def health(self) -> Health:
        """``/healthz``: the process is alive."""
        return self._send(calls.health())

    def ready(self) -> Readiness:
        """``/readyz``: ``ready`` is False (not an error) while active maps are still loading."""
        return self._send(calls.ready())

    def wait_until_ready(self, timeout: float = 60.0, poll_interval: float = 0.1) -> Readiness:
        deadline = time.monotonic() + timeout
        while True:
            status = self.ready()
            if status.ready:
                return status
            if time.monotonic() >= deadline:
                raise JobTimeoutError(f"server not ready after {timeout:.0f}s: pending {status.pending}, "
                                      f"errors {status.errors}")  # fmt: skip
            time.sleep(poll_interval)

    # -- localization -----------------------------------------------------------------------
    def localize(self, map: str, descriptor: ArrayLike | None = None, *,
                 image: ImageSource | None = None, vehicle_id: str | None = None,
                 adaptation: bool | None = None, vehicle_key: str | None = None,
                 reset: bool | None = None, condition: str | None = None) -> Localization:  # fmt: skip
        """One query: a descriptor (d floats, sent as base64 float32) or an encoded image
        (bytes or a file path; the map's stored extractor turns it into a descriptor).
        With ``vehicle_id`` the server adapts the query to that vehicle's earlier ones
        (appearance adaptation; ``adaptation=False`` sends it as it is). The server keeps a
        vehicle's statistics under the ``vehicle_key`` its first answer carries; this client
        remembers it per map and vehicle and sends it again (pass ``vehicle_key`` to use
        another, ``reset=True`` to start the vehicle's drive over). ``condition``: the
        condition the query was taken in (a key the version recorded, ``reference`` or
        ``auto``; :mod:`service.core.query_conditions`)."""
        key = self._keys.key(map, vehicle_id, vehicle_key)
        answer = self._send(calls.localize(map, descriptor, image, vehicle_id, adaptation, key,
                                           reset, condition))  # fmt: skip
        self._keys.remember(map, vehicle_id, answer.vehicle_key)
        return answer

    def localize_batch(self, map: str, descriptors: ArrayLike,
                       condition: str | None = None) -> BatchLocalization:  # fmt: skip
        """Many descriptors (an n × d matrix) in one binary little-endian float32 request,
        standardised by ``condition`` when named."""
        return self._send(calls.localize_batch(map, descriptors, condition))

    def localize_images(self, map: str, images: Sequence[ImageSource],
                        condition: str | None = None) -> BatchLocalization:  # fmt: skip
        return self._send(calls.localize_images(map, images, condition))

    def localize_sequence(
        self, map: str, descriptors: ArrayLike, *, adaptation: bool | None = None,
        odometry: Sequence[float | None] | None = None, condition: str | None = None,
        **filter_params: Any,
    ) -> SequenceLocalization:  # fmt: skip
        """An n × d matrix whose rows are one drive in order: the sequence filter's estimate
        and each frame's own answer; ``filter_params`` (e.g. ``emission_scale=0.2``,
        ``reverse=True``) override the server's filter defaults; ``adaptation`` turns
        appearance adaptation on or off (unset: the server's default); ``odometry``: the
        vehicle's displacement since the previous row, reference frames, one per row;
        ``condition``: the drive's (unset: inferred when the version records conditions)."""
        return self._send(calls.localize_sequence(map, descriptors, filter_params, adaptation,
                                                  odometry, condition))  # fmt: skip

    # -- admin ------------------------------------------------------------------------------
    def upload_route(
        self,
        map: str,
        route: RouteSource | Sequence[RouteSource],
        options: TrainingOptions | None = None,
        *,
        idempotency_key: str | None = None,
        filename: str | None = None,
        places: Sequence[RouteSource] | None = None,
        **params: Any,
    ) -> Job:
        """Upload a route (``.npy``/``.npz`` path, ndarray, or ``.zip``/``.tar`` of images) and
        start training a new version; returns the queued job. A list of routes is several
        traversals of the same places, frame-aligned, or with ``places``: one integer index
        (path or array: the place 0…N−1 of every row) per traversal. ``params`` are
        :class:`TrainingOptions` fields (``trainer="ridge"``, ``rho=0.5``, ``periods=[60, 60]``…).
        Resending with the same ``idempotency_key`` returns the same job."""
        opts = calls.options_of(options, params)
        return self._send(calls.upload_route(map, route, opts, idempotency_key, filename, places),
                          timeout=self.upload_timeout)  # fmt: skip

    def append_traversals(
        self, map: str, version: int, traversals: RouteSource | Sequence[RouteSource], *,
        places: Sequence[RouteSource] | None = None, tags: Sequence[str] = (),
        extend: bool = False, whiten: bool | None = None, activate: bool = False,
    ) -> Version:  # fmt: skip
        """Append one traversal (``.npy`` path, ndarray, or image archive) or several to
        ``version`` of ``map``: the map's next version, built without retraining (its
        ``extra.traversals`` records what it was built from). ``places``: one place index per
        traversal; ``tags``: condition tags ``key=value``; ``extend``: places beyond the route
        extend it; ``activate``: serve it at once."""
        opts = calls.append_options(tags, extend, whiten, activate)
        return self._send(calls.append_traversals(map, version, traversals, opts, places),  # type: ignore[no-any-return]
                          timeout=self.upload_timeout)  # fmt: skip

    def retrain_traversals(
        self, map: str, version: int, traversals: RouteSource | Sequence[RouteSource], *,
        places: Sequence[RouteSource] | None = None, tags: Sequence[str] = (),
        extend: bool = False,
    ) -> Job:  # fmt: skip
        """What an append cannot do (an extension its code's periods cannot label): a
        training job over every traversal ``version`` was built from plus these (as
        :meth:`append_traversals` takes them); follow it with :meth:`wait_for_job`."""
        opts = calls.append_options(tags, extend, None, False, retrain=True)
        return self._send(calls.append_traversals(map, version, traversals, opts, places),  # type: ignore[no-any-return]
                          timeout=self.upload_timeout)  # fmt: skip

    def get_job(self, job_id: str) -> Job:
        return self._send(calls.get_job(job_id))

    def list_jobs(self, map: str | None = None, states: Sequence[str] | None = None,
                  limit: int = 50, cursor: str | None = None) -> JobPage:  # fmt: skip
        """One page of training jobs, newest first (``next_cursor`` fetches the next)."""
        return self._send(calls.list_jobs(map, states, limit, cursor))

    def wait_for_job(self, job_id: str, timeout: float = 600.0, poll_interval: float = 0.25,
                     on_update: JobCallback | None = None) -> Job:  # fmt: skip
        """Poll until the job is ``succeeded`` or ``failed`` (returned either way); raises
        :class:`JobTimeoutError` after ``timeout`` seconds. ``on_update`` sees every poll."""
        deadline = time.monotonic() + timeout
        while True:
            job = self.get_job(job_id)
            if on_update is not None:
                on_update(job)
            if job.done:
                return job
            if time.monotonic() >= deadline:
                raise JobTimeoutError(f"job {job_id} still {job.state} ({job.stage}) after {timeout:.0f}s",
                                      job_id=job_id)  # fmt: skip
            time.sleep(poll_interval)

    def list_maps(self) -> list[MapSummary]:
        return self._send(calls.list_maps())

    def get_map(self, name: str) -> MapDetail:
        """A map, its active version and the version this server process is serving."""
        return self._send(calls.get_map(name))

    def list_versions(self, name: str) -> list[Version]:
        return self._send(calls.list_versions(name))

    def get_version(self, name: str, version: int) -> Version:
        return self._send(calls.get_version(name, version))

    def activate(self, name: str, version: int) -> Version:
        """Serve ``version`` of ``name`` (promote or roll back; the server hot-swaps)."""
        return self._send(calls.activate(name, version))

    def deactivate(self, name: str) -> MapSummary:
        """Take a map out of service (localize answers 409 until a version is activated)."""
        return self._send(calls.deactivate(name))

    def delete_version(self, name: str, version: int) -> None:
        """Delete an inactive version (409 for the active one)."""
        self._send(calls.delete_version(name, version))

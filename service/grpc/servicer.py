"""``gridplace.v1.Localization``: every call goes to the service layer shared with REST.

Handlers run on the gRPC server's own event loop (see :mod:`service.grpc.server`) but never do
CPU or registry work on it: that runs in the server's bounded thread pools (:class:`Workers`),
unary ``Localize`` calls and admin calls in one, stream frames in the other, so a large request
cannot hold up other callers' messages, nor use every thread streams need. A stream's frames
are still answered one after another, in order. Each method has its own message-size cap
(``GRIDPLACE_MAX_PUBLIC_BODY_MB`` for ``Localize``, ``GRIDPLACE_MAX_STREAM_FRAME_KB`` per
stream message); the server refuses anything larger than the largest cap before a handler runs.

With the micro-batcher (:mod:`service.core.batching`, on unless ``GRIDPLACE_BATCHING=false``)
descriptor ``Localize`` calls and every stream frame go to its worker thread instead, which
localizes the frames of all concurrent streams and unary calls together; a ``LocalizeStream``
then reads ahead up to ``STREAM_READ_AHEAD`` frames (at most ``STREAM_READ_AHEAD_BYTES`` of
messages) and answers them in order. A stream holds a lease on the server-wide stream budget
(:mod:`service.core.stream_budget`: ``GRIDPLACE_MAX_STREAMS`` streams, their vehicles and
bytes); a stream beyond it is refused with ``RESOURCE_EXHAUSTED``, and a closed stream's
vehicles are dropped and their memory given back. An accepted stream's initial metadata
(``gridplace-stream: open``) comes at once, before any frame: a client that awaits it before
sending learns of a refusal from its status, not from a write that raced the server's close
(which gRPC's Python client reports as ``INTERNAL``).
Unary errors abort the call with the status of the error's class (``GridplaceError.grpc_status``)
and its code in the ``gridplace-error`` trailing metadata; in ``LocalizeStream`` a bad message
is answered with ``error`` set and the stream goes on.
"""

from __future__ import annotations

import asyncio
import functools
import logging
from collections.abc import AsyncIterator, Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any, NoReturn, TypeVar

import grpc

from service.api.auth import check_admin
from service.core.batching import MAX_BATCHED_BYTES
from service.core.context import ServiceContext
from service.core.streams import FleetStream
from service.encoding.sequence import SequenceConfig
from service.errors import EmptyInputError, GridplaceError, PayloadTooLargeError
from service.grpc import messages
from service.grpc.gen import localization_pb2 as pb
from service.grpc.gen import localization_pb2_grpc as pb_grpc
from service.settings import Settings

STREAM_OPEN = (("gridplace-stream", "open"),)  # an accepted stream's initial metadata
log = logging.getLogger("gridplace.grpc")
T = TypeVar("T")

SERVICE_NAME = pb.DESCRIPTOR.services_by_name["Localization"].full_name
ADMIN_MESSAGE_BYTES = 64 * 1024  # ListMaps / GetMap requests carry a name at most
STREAM_READ_AHEAD = 64  # frames of one stream in flight at once (the stream's backpressure)
STREAM_READ_AHEAD_BYTES = 4 * 1024 * 1024  # and the most bytes of messages they hold together


@dataclass(frozen=True)
class Workers:
    """The thread pools handlers hand their work to, and the per-method size caps."""

    unary: ThreadPoolExecutor  # Localize and admin calls
    frames: ThreadPoolExecutor  # LocalizeStream frames
    max_localize_bytes: int
    max_frame_bytes: int

    @classmethod
    def from_settings(cls, settings: Settings) -> Workers:
        unary = max(1, settings.grpc_workers // 2)
        return cls(
            ThreadPoolExecutor(unary, thread_name_prefix="gridplace-grpc-unary"),
            ThreadPoolExecutor(max(1, settings.grpc_workers - unary),
                               thread_name_prefix="gridplace-grpc-frames"),
            settings.max_public_body_mb * 1024 * 1024, settings.max_stream_frame_kb * 1024,
        )  # fmt: skip

    @property
    def max_message_bytes(self) -> int:
        return max(self.max_localize_bytes, self.max_frame_bytes, ADMIN_MESSAGE_BYTES)

    def shutdown(self) -> None:
        self.unary.shutdown(wait=True, cancel_futures=True)
        self.frames.shutdown(wait=True, cancel_futures=True)


def _check_size(size: int, limit: int, what: str, setting: str) -> None:
    if size > limit:
        raise PayloadTooLargeError(
            f"{what} of {size} bytes exceeds the {limit}-byte limit ({setting})", limit_bytes=limit
        )


async def _off_loop(executor: ThreadPoolExecutor, fn: Callable[..., T], *args: Any) -> T:
    return await asyncio.get_running_loop().run_in_executor(executor, functools.partial(fn, *args))


def _internal() -> GridplaceError:
    """What a caller sees of an unexpected server fault (logged with its traceback)."""
    return GridplaceError("internal server error")


async def _abort(context: grpc.aio.ServicerContext, exc: GridplaceError) -> NoReturn:
    if exc.http_status >= 500:
        log.error("%s: %s", exc.code, exc.message)
    await context.abort(messages.status_code(exc), exc.message,
                        trailing_metadata=(("gridplace-error", exc.code),))  # fmt: skip
    raise AssertionError("unreachable")  # context.abort raises


def _frame_error(request: pb.StreamRequest, exc: Exception) -> pb.StreamResponse:
    """A stream frame's error answer (an unexpected one is logged and answered as internal)."""
    if isinstance(exc, GridplaceError):
        return messages.stream_error(request, exc)
    log.error("LocalizeStream frame %s of %r failed", request.sequence, request.vehicle_id,
              exc_info=exc)  # fmt: skip
    return messages.stream_error(request, _internal())


class LocalizationServicer(pb_grpc.LocalizationServicer):
    def __init__(self, context: ServiceContext, workers: Workers,
                 sequence: SequenceConfig | None = None) -> None:  # fmt: skip
        self.ctx = context
        self.service = context.service
        self.workers = workers
        self.sequence = sequence or SequenceConfig()

    async def Localize(self, request: pb.LocalizeRequest, context: grpc.aio.ServicerContext) -> pb.LocalizeResponse:
        try:
            size = request.ByteSize()
            _check_size(size, self.workers.max_localize_bytes, "a Localize request",
                        "GRIDPLACE_MAX_PUBLIC_BODY_MB")  # fmt: skip
            assert self.ctx.public is not None
            with self.ctx.public.open(size):  # public calls in flight: a server-wide budget
                batcher = self.ctx.batcher
                if (batcher is not None and request.WhichOneof("query") == "descriptor"
                        and len(request.descriptor) <= MAX_BATCHED_BYTES
                        and not request.condition):  # fmt: skip
                    result = await batcher.localize_bytes(request.map, request.descriptor,
                                                          request.dimension or None)  # fmt: skip
                    return messages.localize_response(result)
                return await _off_loop(self.workers.unary, self._localize, request)
        except GridplaceError as exc:
            await _abort(context, exc)
        except Exception:
            log.exception("Localize failed")
            await _abort(context, _internal())

    def _localize(self, request: pb.LocalizeRequest) -> pb.LocalizeResponse:
        which = request.WhichOneof("query")
        if which == "descriptor":
            result = self.service.localize_bytes(request.map, request.descriptor,
                                                 request.dimension or None,
                                                 request.condition or None)  # fmt: skip
        elif which == "image":
            result = self.service.localize_images(request.map, [("image", request.image)],
                                                  request.condition or None)  # fmt: skip
        else:
            raise EmptyInputError("send a descriptor (float32 bytes) or an image")
        return messages.localize_response(result)

    async def LocalizeStream(
        self, request_iterator: AsyncIterator[pb.StreamRequest], context: grpc.aio.ServicerContext
    ) -> AsyncIterator[pb.StreamResponse]:
        stream = await self._open_stream(context)
        batcher = self.ctx.batcher
        try:
            if batcher is None:
                async for request in request_iterator:
                    try:
                        self._check_frame(request)
                        answer = await _off_loop(self.workers.frames, stream.answer,
                                                 messages.frame(request))  # fmt: skip
                        yield messages.stream_response(answer)
                    except Exception as exc:  # noqa: BLE001 - answered in-stream, the stream goes on
                        yield _frame_error(request, exc)
                return
            pending: asyncio.Queue[tuple[pb.StreamRequest, int, asyncio.Future[Any]] | None] = (
                asyncio.Queue(STREAM_READ_AHEAD)
            )
            held = 0  # bytes of the messages read ahead
            room = asyncio.Event()

            async def read() -> None:
                nonlocal held
                try:
                    async for request in request_iterator:
                        size = 0
                        try:
                            size = self._check_frame(request)
                            answer = batcher.frame(stream, messages.frame(request))
                        except GridplaceError as exc:
                            answer = asyncio.get_running_loop().create_future()
                            answer.set_exception(exc)
                        while held and held + size > STREAM_READ_AHEAD_BYTES:
                            room.clear()
                            await room.wait()
                        held += size
                        await pending.put((request, size, answer))
                finally:
                    await pending.put(None)

            reader = asyncio.create_task(read())
            try:
                while (item := await pending.get()) is not None:
                    request, size, answer = item
                    try:
                        yield messages.stream_response(await answer)
                    except Exception as exc:  # noqa: BLE001 - answered in-stream, the stream goes on
                        yield _frame_error(request, exc)
                    held -= size
                    room.set()
                await reader  # the client's stream ended: surface a broken one
            finally:
                reader.cancel()
        finally:  # off the loop: dropping many vehicles' state and trimming the heap take time
            try:
                asyncio.get_running_loop().run_in_executor(self.workers.frames, stream.close)
            except RuntimeError:  # the pool is shut down: the server is stopping
                stream.close()

    async def _open_stream(self, context: grpc.aio.ServicerContext) -> FleetStream:
        """A new stream's state, with its lease on the server-wide budget (the call is aborted
        with ``RESOURCE_EXHAUSTED`` when every stream the server allows is open)."""
        settings, budget = self.ctx.settings, self.ctx.streams
        assert budget is not None
        try:
            lease = budget.open()
        except GridplaceError as exc:
            await _abort(context, exc)
        try:  # the stream is accepted: a client that awaits the initial metadata sends then
            await context.send_initial_metadata(STREAM_OPEN)
        except BaseException:
            lease.close()
            raise
        return FleetStream(self.service, self.sequence, adaptation=settings.adaptation(),
                           adapt_by_default=settings.drive_adaptation, lease=lease,
                           condition_frames=settings.condition_frames)  # fmt: skip

    def _check_frame(self, request: pb.StreamRequest) -> int:
        """The message's size, checked against its cap."""
        size = request.ByteSize()
        _check_size(size, self.workers.max_frame_bytes, "a stream message",
                    "GRIDPLACE_MAX_STREAM_FRAME_KB")  # fmt: skip
        return size

    async def ListMaps(self, request: pb.ListMapsRequest, context: grpc.aio.ServicerContext) -> pb.ListMapsResponse:
        try:
            self._admin(context, request)
            maps = await _off_loop(self.workers.unary, self.service.list_maps)
            return pb.ListMapsResponse(maps=[messages.map_info(m, self._serving(m.name)) for m in maps])
        except GridplaceError as exc:
            await _abort(context, exc)

    async def GetMap(self, request: pb.GetMapRequest, context: grpc.aio.ServicerContext) -> pb.MapInfo:
        try:
            self._admin(context, request)
            return await _off_loop(self.workers.unary, self._get_map, request.name)
        except GridplaceError as exc:
            await _abort(context, exc)

    def _get_map(self, name: str) -> pb.MapInfo:
        info = self.service.get_map(name)
        active = None
        if info.active_version is not None:
            active = self.service.get_version(info.name, info.active_version)
        return messages.map_info(info, self._serving(info.name), active)

    def _admin(self, context: grpc.aio.ServicerContext, request: Any) -> None:
        """Maps and versions are admin calls, as on REST (``authorization: Bearer <token>``)."""
        _check_size(request.ByteSize(), ADMIN_MESSAGE_BYTES, "an admin request",
                    "fixed: admin requests carry a map name at most")  # fmt: skip
        metadata: Any = context.invocation_metadata() or ()
        authorization = next((str(v) for k, v in metadata if k == "authorization"), None)
        check_admin(self.ctx.settings, authorization)

    def _serving(self, name: str) -> int | None:
        loaded = self.ctx.store.get(name)
        return None if loaded is None else loaded.version

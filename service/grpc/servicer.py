"""``gridplace.v1.Localization``: every call goes to the service layer shared with REST.

Handlers run on the gRPC server's own event loop (see :mod:`service.grpc.server`) and call the
service layer inline: one frame is a few hundred microseconds of NumPy, less than a hop to a
thread pool would cost, and a stream's frames must be answered one after another anyway.
Unary errors abort the call with the status of the error's class (``GridplaceError.grpc_status``)
and its code in the ``gridplace-error`` trailing metadata; in ``LocalizeStream`` a bad message
is answered with ``error`` set and the stream goes on.
"""

from __future__ import annotations

import logging
from collections.abc import AsyncIterator
from typing import Any, NoReturn

import grpc

from service.api.auth import check_admin
from service.core.context import ServiceContext
from service.core.streams import FleetStream
from service.encoding.sequence import SequenceConfig
from service.errors import EmptyInputError, GridplaceError
from service.grpc import messages
from service.grpc.gen import localization_pb2 as pb
from service.grpc.gen import localization_pb2_grpc as pb_grpc

log = logging.getLogger("gridplace.grpc")

SERVICE_NAME = pb.DESCRIPTOR.services_by_name["Localization"].full_name


def _internal() -> GridplaceError:
    """What a caller sees of an unexpected server fault (logged with its traceback)."""
    return GridplaceError("internal server error")


async def _abort(context: grpc.aio.ServicerContext, exc: GridplaceError) -> NoReturn:
    if exc.http_status >= 500:
        log.error("%s: %s", exc.code, exc.message)
    await context.abort(messages.status_code(exc), exc.message,
                        trailing_metadata=(("gridplace-error", exc.code),))  # fmt: skip
    raise AssertionError("unreachable")  # context.abort raises


class LocalizationServicer(pb_grpc.LocalizationServicer):
    def __init__(self, context: ServiceContext, sequence: SequenceConfig | None = None) -> None:
        self.ctx = context
        self.service = context.service
        self.sequence = sequence or SequenceConfig()

    async def Localize(self, request: pb.LocalizeRequest, context: grpc.aio.ServicerContext) -> pb.LocalizeResponse:
        try:
            which = request.WhichOneof("query")
            if which == "descriptor":
                result = self.service.localize_bytes(request.map, request.descriptor,
                                                     request.dimension or None)  # fmt: skip
            elif which == "image":
                result = self.service.localize_images(request.map, [("image", request.image)])
            else:
                raise EmptyInputError("send a descriptor (float32 bytes) or an image")
            return messages.localize_response(result)
        except GridplaceError as exc:
            await _abort(context, exc)
        except Exception:
            log.exception("Localize failed")
            await _abort(context, _internal())

    async def LocalizeStream(
        self, request_iterator: AsyncIterator[pb.StreamRequest], context: grpc.aio.ServicerContext
    ) -> AsyncIterator[pb.StreamResponse]:
        stream = FleetStream(self.service, self.sequence)
        async for request in request_iterator:
            try:
                yield messages.stream_response(stream.answer(messages.frame(request)))
            except GridplaceError as exc:
                yield messages.stream_error(request, exc)
            except Exception:
                log.exception("LocalizeStream frame %s of %r failed", request.sequence,
                              request.vehicle_id)  # fmt: skip
                yield messages.stream_error(request, _internal())

    async def ListMaps(self, request: pb.ListMapsRequest, context: grpc.aio.ServicerContext) -> pb.ListMapsResponse:
        try:
            self._admin(context)
            maps = self.service.list_maps()
            return pb.ListMapsResponse(maps=[messages.map_info(m, self._serving(m.name)) for m in maps])
        except GridplaceError as exc:
            await _abort(context, exc)

    async def GetMap(self, request: pb.GetMapRequest, context: grpc.aio.ServicerContext) -> pb.MapInfo:
        try:
            self._admin(context)
            info = self.service.get_map(request.name)
            active = None
            if info.active_version is not None:
                active = self.service.get_version(info.name, info.active_version)
            return messages.map_info(info, self._serving(info.name), active)
        except GridplaceError as exc:
            await _abort(context, exc)

    def _admin(self, context: grpc.aio.ServicerContext) -> None:
        """Maps and versions are admin calls, as on REST (``authorization: Bearer <token>``)."""
        metadata: Any = context.invocation_metadata() or ()
        authorization = next((str(v) for k, v in metadata if k == "authorization"), None)
        check_admin(self.ctx.settings, authorization)

    def _serving(self, name: str) -> int | None:
        loaded = self.ctx.store.get(name)
        return None if loaded is None else loaded.version

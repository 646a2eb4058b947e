"""Conversions between the service layer's results and ``gridplace.v1`` messages."""

from __future__ import annotations

from datetime import UTC, datetime
from typing import TYPE_CHECKING

import grpc
from google.protobuf.timestamp_pb2 import Timestamp

from service.core.localization import LocalizeResult
from service.core.streams import Frame, FrameAnswer
from service.errors import GridplaceError
from service.grpc.gen import localization_pb2 as pb

if TYPE_CHECKING:
    from service.registry import MapInfo, VersionInfo


def status_code(exc: GridplaceError) -> grpc.StatusCode:
    """The gRPC status of an error of the one hierarchy (its ``grpc_status`` name)."""
    return getattr(grpc.StatusCode, exc.grpc_status, grpc.StatusCode.INTERNAL)  # type: ignore[no-any-return]


def error_message(exc: GridplaceError) -> pb.Error:
    return pb.Error(code=exc.code, status=exc.grpc_status, message=exc.message)


def _timestamp(value: datetime) -> Timestamp:
    ts = Timestamp()
    ts.FromDatetime(value if value.tzinfo else value.replace(tzinfo=UTC))
    return ts


def localize_response(result: LocalizeResult) -> pb.LocalizeResponse:
    matches = [pb.Match(index=int(i), chunk=int(c), confidence=float(p))
               for i, c, p in zip(result.index, result.chunk, result.confidence, strict=True)]  # fmt: skip
    return pb.LocalizeResponse(map=result.map, version=result.version, matches=matches,
                               latency_ms=result.latency_ms, condition=result.condition or "")  # fmt: skip


def frame(request: pb.StreamRequest) -> Frame:
    which = request.WhichOneof("query")
    return Frame(
        vehicle_id=request.vehicle_id,
        sequence=request.sequence,
        map=request.map,
        descriptor=request.descriptor if which == "descriptor" else None,
        image=request.image if which == "image" else None,
        sequence_filter=request.sequence_filter,
        reset=request.reset_sequence,
        adapt=_ADAPT.get(request.adaptation),
        odometry=request.odometry if request.HasField("odometry") else None,
        odometry_m=request.odometry_m if request.HasField("odometry_m") else None,
        condition=request.condition or None,
    )


_ADAPT: dict[int, bool] = {pb.ADAPTATION_ON: True, pb.ADAPTATION_OFF: False}  # else: default


def stream_response(a: FrameAnswer) -> pb.StreamResponse:
    return pb.StreamResponse(
        vehicle_id=a.vehicle_id, sequence=a.sequence, map=a.map, version=a.version,
        index=a.index, chunk=a.chunk, confidence=a.confidence, filtered=a.filtered,
        raw_index=a.raw_index, raw_confidence=a.raw_confidence, frames_used=a.frames_used,
        latency_ms=a.latency_ms, adapted=a.adapted,
        vehicle_state=a.vehicle_state, condition=a.condition,
    )  # fmt: skip


def stream_error(request: pb.StreamRequest, exc: GridplaceError) -> pb.StreamResponse:
    return pb.StreamResponse(vehicle_id=request.vehicle_id, sequence=request.sequence,
                             map=request.map, error=error_message(exc))  # fmt: skip


def version_info(v: VersionInfo) -> pb.VersionInfo:
    return pb.VersionInfo(
        version=v.version, n_frames=v.n_frames, n_features=v.n_features, kind=v.kind,
        sha256=v.sha256, artifact_bytes=v.artifact_bytes,
        paper_bytes=int(v.footprint.get("paper_bytes", 0)),
        image_extractor=v.extractor is not None, created_at=_timestamp(v.created_at),
        n_traversals=v.n_traversals,
    )  # fmt: skip


def map_info(m: MapInfo, serving: int | None, active: VersionInfo | None = None) -> pb.MapInfo:
    out = pb.MapInfo(name=m.name, versions=m.versions, created_at=_timestamp(m.created_at))
    if m.active_version is not None:
        out.active_version = m.active_version
    if serving is not None:
        out.serving_version = serving
    if active is not None:
        out.active.CopyFrom(version_info(active))
    return out

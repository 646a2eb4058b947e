import datetime

from google.protobuf import timestamp_pb2 as _timestamp_pb2
from google.protobuf.internal import containers as _containers
from google.protobuf.internal import enum_type_wrapper as _enum_type_wrapper
from google.protobuf import descriptor as _descriptor
from google.protobuf import message as _message
from collections.abc import Iterable as _Iterable, Mapping as _Mapping
from typing import ClassVar as _ClassVar, Optional as _Optional, Union as _Union

DESCRIPTOR: _descriptor.FileDescriptor

class Adaptation(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
    __slots__ = ()
    ADAPTATION_DEFAULT: _ClassVar[Adaptation]
    ADAPTATION_ON: _ClassVar[Adaptation]
    ADAPTATION_OFF: _ClassVar[Adaptation]
ADAPTATION_DEFAULT: Adaptation
ADAPTATION_ON: Adaptation
ADAPTATION_OFF: Adaptation

class LocalizeRequest(_message.Message):
    __slots__ = ("map", "descriptor", "image", "dimension", "condition")
    MAP_FIELD_NUMBER: _ClassVar[int]
    DESCRIPTOR_FIELD_NUMBER: _ClassVar[int]
    IMAGE_FIELD_NUMBER: _ClassVar[int]
    DIMENSION_FIELD_NUMBER: _ClassVar[int]
    CONDITION_FIELD_NUMBER: _ClassVar[int]
    map: str
    descriptor: bytes
    image: bytes
    dimension: int
    condition: str
    def __init__(self, map: _Optional[str] = ..., descriptor: _Optional[bytes] = ..., image: _Optional[bytes] = ..., dimension: _Optional[int] = ..., condition: _Optional[str] = ...) -> None: ...

class Match(_message.Message):
    __slots__ = ("index", "chunk", "confidence")
    INDEX_FIELD_NUMBER: _ClassVar[int]
    CHUNK_FIELD_NUMBER: _ClassVar[int]
    CONFIDENCE_FIELD_NUMBER: _ClassVar[int]
    index: int
    chunk: int
    confidence: float
    def __init__(self, index: _Optional[int] = ..., chunk: _Optional[int] = ..., confidence: _Optional[float] = ...) -> None: ...

class LocalizeResponse(_message.Message):
    __slots__ = ("map", "version", "matches", "latency_ms", "condition")
    MAP_FIELD_NUMBER: _ClassVar[int]
    VERSION_FIELD_NUMBER: _ClassVar[int]
    MATCHES_FIELD_NUMBER: _ClassVar[int]
    LATENCY_MS_FIELD_NUMBER: _ClassVar[int]
    CONDITION_FIELD_NUMBER: _ClassVar[int]
    map: str
    version: int
    matches: _containers.RepeatedCompositeFieldContainer[Match]
    latency_ms: float
    condition: str
    def __init__(self, map: _Optional[str] = ..., version: _Optional[int] = ..., matches: _Optional[_Iterable[_Union[Match, _Mapping]]] = ..., latency_ms: _Optional[float] = ..., condition: _Optional[str] = ...) -> None: ...

class StreamRequest(_message.Message):
    __slots__ = ("vehicle_id", "sequence", "map", "descriptor", "image", "sequence_filter", "reset_sequence", "adaptation", "odometry", "odometry_m", "condition")
    VEHICLE_ID_FIELD_NUMBER: _ClassVar[int]
    SEQUENCE_FIELD_NUMBER: _ClassVar[int]
    MAP_FIELD_NUMBER: _ClassVar[int]
    DESCRIPTOR_FIELD_NUMBER: _ClassVar[int]
    IMAGE_FIELD_NUMBER: _ClassVar[int]
    SEQUENCE_FILTER_FIELD_NUMBER: _ClassVar[int]
    RESET_SEQUENCE_FIELD_NUMBER: _ClassVar[int]
    ADAPTATION_FIELD_NUMBER: _ClassVar[int]
    ODOMETRY_FIELD_NUMBER: _ClassVar[int]
    ODOMETRY_M_FIELD_NUMBER: _ClassVar[int]
    CONDITION_FIELD_NUMBER: _ClassVar[int]
    vehicle_id: str
    sequence: int
    map: str
    descriptor: bytes
    image: bytes
    sequence_filter: bool
    reset_sequence: bool
    adaptation: Adaptation
    odometry: float
    odometry_m: float
    condition: str
    def __init__(self, vehicle_id: _Optional[str] = ..., sequence: _Optional[int] = ..., map: _Optional[str] = ..., descriptor: _Optional[bytes] = ..., image: _Optional[bytes] = ..., sequence_filter: _Optional[bool] = ..., reset_sequence: _Optional[bool] = ..., adaptation: _Optional[_Union[Adaptation, str]] = ..., odometry: _Optional[float] = ..., odometry_m: _Optional[float] = ..., condition: _Optional[str] = ...) -> None: ...

class Error(_message.Message):
    __slots__ = ("code", "status", "message")
    CODE_FIELD_NUMBER: _ClassVar[int]
    STATUS_FIELD_NUMBER: _ClassVar[int]
    MESSAGE_FIELD_NUMBER: _ClassVar[int]
    code: str
    status: str
    message: str
    def __init__(self, code: _Optional[str] = ..., status: _Optional[str] = ..., message: _Optional[str] = ...) -> None: ...

class StreamResponse(_message.Message):
    __slots__ = ("vehicle_id", "sequence", "map", "version", "index", "chunk", "confidence", "filtered", "raw_index", "raw_confidence", "frames_used", "latency_ms", "error", "adapted", "vehicle_state", "condition")
    VEHICLE_ID_FIELD_NUMBER: _ClassVar[int]
    SEQUENCE_FIELD_NUMBER: _ClassVar[int]
    MAP_FIELD_NUMBER: _ClassVar[int]
    VERSION_FIELD_NUMBER: _ClassVar[int]
    INDEX_FIELD_NUMBER: _ClassVar[int]
    CHUNK_FIELD_NUMBER: _ClassVar[int]
    CONFIDENCE_FIELD_NUMBER: _ClassVar[int]
    FILTERED_FIELD_NUMBER: _ClassVar[int]
    RAW_INDEX_FIELD_NUMBER: _ClassVar[int]
    RAW_CONFIDENCE_FIELD_NUMBER: _ClassVar[int]
    FRAMES_USED_FIELD_NUMBER: _ClassVar[int]
    LATENCY_MS_FIELD_NUMBER: _ClassVar[int]
    ERROR_FIELD_NUMBER: _ClassVar[int]
    ADAPTED_FIELD_NUMBER: _ClassVar[int]
    VEHICLE_STATE_FIELD_NUMBER: _ClassVar[int]
    CONDITION_FIELD_NUMBER: _ClassVar[int]
    vehicle_id: str
    sequence: int
    map: str
    version: int
    index: int
    chunk: int
    confidence: float
    filtered: bool
    raw_index: int
    raw_confidence: float
    frames_used: int
    latency_ms: float
    error: Error
    adapted: bool
    vehicle_state: str
    condition: str
    def __init__(self, vehicle_id: _Optional[str] = ..., sequence: _Optional[int] = ..., map: _Optional[str] = ..., version: _Optional[int] = ..., index: _Optional[int] = ..., chunk: _Optional[int] = ..., confidence: _Optional[float] = ..., filtered: _Optional[bool] = ..., raw_index: _Optional[int] = ..., raw_confidence: _Optional[float] = ..., frames_used: _Optional[int] = ..., latency_ms: _Optional[float] = ..., error: _Optional[_Union[Error, _Mapping]] = ..., adapted: _Optional[bool] = ..., vehicle_state: _Optional[str] = ..., condition: _Optional[str] = ...) -> None: ...

class ListMapsRequest(_message.Message):
    __slots__ = ()
    def __init__(self) -> None: ...

class ListMapsResponse(_message.Message):
    __slots__ = ("maps",)
    MAPS_FIELD_NUMBER: _ClassVar[int]
    maps: _containers.RepeatedCompositeFieldContainer[MapInfo]
    def __init__(self, maps: _Optional[_Iterable[_Union[MapInfo, _Mapping]]] = ...) -> None: ...

class GetMapRequest(_message.Message):
    __slots__ = ("name",)
    NAME_FIELD_NUMBER: _ClassVar[int]
    name: str
    def __init__(self, name: _Optional[str] = ...) -> None: ...

class VersionInfo(_message.Message):
    __slots__ = ("version", "n_frames", "n_features", "kind", "sha256", "artifact_bytes", "paper_bytes", "image_extractor", "created_at", "n_traversals")
    VERSION_FIELD_NUMBER: _ClassVar[int]
    N_FRAMES_FIELD_NUMBER: _ClassVar[int]
    N_FEATURES_FIELD_NUMBER: _ClassVar[int]
    KIND_FIELD_NUMBER: _ClassVar[int]
    SHA256_FIELD_NUMBER: _ClassVar[int]
    ARTIFACT_BYTES_FIELD_NUMBER: _ClassVar[int]
    PAPER_BYTES_FIELD_NUMBER: _ClassVar[int]
    IMAGE_EXTRACTOR_FIELD_NUMBER: _ClassVar[int]
    CREATED_AT_FIELD_NUMBER: _ClassVar[int]
    N_TRAVERSALS_FIELD_NUMBER: _ClassVar[int]
    version: int
    n_frames: int
    n_features: int
    kind: str
    sha256: str
    artifact_bytes: int
    paper_bytes: int
    image_extractor: bool
    created_at: _timestamp_pb2.Timestamp
    n_traversals: int
    def __init__(self, version: _Optional[int] = ..., n_frames: _Optional[int] = ..., n_features: _Optional[int] = ..., kind: _Optional[str] = ..., sha256: _Optional[str] = ..., artifact_bytes: _Optional[int] = ..., paper_bytes: _Optional[int] = ..., image_extractor: _Optional[bool] = ..., created_at: _Optional[_Union[datetime.datetime, _timestamp_pb2.Timestamp, _Mapping]] = ..., n_traversals: _Optional[int] = ...) -> None: ...

class MapInfo(_message.Message):
    __slots__ = ("name", "active_version", "versions", "created_at", "serving_version", "active")
    NAME_FIELD_NUMBER: _ClassVar[int]
    ACTIVE_VERSION_FIELD_NUMBER: _ClassVar[int]
    VERSIONS_FIELD_NUMBER: _ClassVar[int]
    CREATED_AT_FIELD_NUMBER: _ClassVar[int]
    SERVING_VERSION_FIELD_NUMBER: _ClassVar[int]
    ACTIVE_FIELD_NUMBER: _ClassVar[int]
    name: str
    active_version: int
    versions: _containers.RepeatedScalarFieldContainer[int]
    created_at: _timestamp_pb2.Timestamp
    serving_version: int
    active: VersionInfo
    def __init__(self, name: _Optional[str] = ..., active_version: _Optional[int] = ..., versions: _Optional[_Iterable[int]] = ..., created_at: _Optional[_Union[datetime.datetime, _timestamp_pb2.Timestamp, _Mapping]] = ..., serving_version: _Optional[int] = ..., active: _Optional[_Union[VersionInfo, _Mapping]] = ...) -> None: ...

"""The versioned registry of maps, immutable model versions and training jobs (SQLite or PostgreSQL)."""

from service.registry.models import (
    TERMINAL_STATES,
    JobInfo,
    JobRetry,
    JobSpec,
    JobState,
    MapInfo,
    RouteSource,
    VersionInfo,
)
from service.registry.names import MAP_NAME_PATTERN, check_map_name, check_version
from service.registry.registry import Registry

__all__ = [
    "MAP_NAME_PATTERN",
    "TERMINAL_STATES",
    "JobInfo",
    "JobRetry",
    "JobSpec",
    "JobState",
    "MapInfo",
    "Registry",
    "RouteSource",
    "VersionInfo",
    "check_map_name",
    "check_version",
]

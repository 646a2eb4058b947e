"""The wire format of the gridplace REST API: every request and answer body, once.

The server (``service.api`` builds its OpenAPI schema from these models) and the client
(``service.client`` parses answers with them) import the same classes, and the registry
returns them, so a field is declared in one place. This package depends on pydantic and the
standard library only: importing it (or ``service.client``) pulls in no server code.

Conventions for a new body:

* one concept per module (``localize``, ``maps``, ``jobs``, ``training``…), re-exported here;
* a body the server sends subclasses :class:`Answer` (frozen; unknown fields ignored so a
  newer server never breaks an older client; validated from attributes of any object);
* a body a client sends subclasses :class:`Request` (unknown fields refused);
* constraints are the server's real rules (``ge``/``le``/``pattern``/``min_length``, "exactly
  one of" via :func:`exactly_one_of`), so the OpenAPI schema accepts exactly what the server
  accepts; data-dependent rules (a descriptor's width against the map) stay server-side;
* error bodies are :class:`ErrorBody`; their ``error`` codes are the ``code`` of the classes
  in :mod:`service.errors` (``service.errors.error_class`` maps a code back).
"""

from service.wire.appends import AppendOptions, parse_tags
from service.wire.base import (
    JOB_STATES,
    MAP_NAME_PATTERN,
    MAX_VERSION,
    TERMINAL_STATES,
    Answer,
    JobState,
    MapName,
    Request,
    VersionNumber,
    exactly_one_of,
)
from service.wire.errors import ErrorBody
from service.wire.health import Health, Readiness
from service.wire.jobs import Job, JobPage, JobProgress, JobRetry, PartProgress
from service.wire.localize import (
    BatchLocalization,
    BatchLocalizeRequest,
    Localization,
    LocalizeRequest,
    VehicleOptions,
)
from service.wire.maps import MapDetail, MapSummary, Version
from service.wire.sequence import (
    SequenceFilterOptions,
    SequenceLocalization,
    SequenceLocalizeRequest,
)
from service.wire.training import TrainingOptions

__all__ = [
    "JOB_STATES",
    "MAP_NAME_PATTERN",
    "MAX_VERSION",
    "TERMINAL_STATES",
    "Answer",
    "AppendOptions",
    "BatchLocalization",
    "BatchLocalizeRequest",
    "ErrorBody",
    "Health",
    "Job",
    "JobPage",
    "JobProgress",
    "JobRetry",
    "JobState",
    "Localization",
    "LocalizeRequest",
    "MapDetail",
    "MapName",
    "MapSummary",
    "PartProgress",
    "Readiness",
    "Request",
    "SequenceFilterOptions",
    "SequenceLocalization",
    "SequenceLocalizeRequest",
    "TrainingOptions",
    "VehicleOptions",
    "Version",
    "VersionNumber",
    "exactly_one_of",
    "parse_tags",
]

"""A typed Python client of the gridplace REST API (httpx; sync and asyncio).

Errors raise the classes of :mod:`service.errors` (the server's ``error`` codes mapped back);
no answer at all raises :class:`ServerUnreachableError` (an ``UnavailableError``)."""

from service.client.async_client import AsyncGridplaceClient
from service.client.client import GridplaceClient
from service.client.errors import (
    JobFailedError,
    JobTimeoutError,
    RequestValidationError,
    ServerUnreachableError,
    UnexpectedResponseError,
    error_from_response,
)
from service.wire import (
    BatchLocalization,
    Health,
    Job,
    Localization,
    MapDetail,
    MapSummary,
    Readiness,
    SequenceLocalization,
    TrainingOptions,
    Version,
)

__all__ = [
    "AsyncGridplaceClient",
    "BatchLocalization",
    "GridplaceClient",
    "Health",
    "Job",
    "JobFailedError",
    "JobTimeoutError",
    "Localization",
    "MapDetail",
    "MapSummary",
    "Readiness",
    "RequestValidationError",
    "SequenceLocalization",
    "ServerUnreachableError",
    "TrainingOptions",
    "UnexpectedResponseError",
    "Version",
    "error_from_response",
]

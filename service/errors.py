"""The one error hierarchy of gridplace.

Every error a caller can cause or observe is a :class:`GridplaceError`. Each class carries
the HTTP status and the gRPC status-code *name* it maps to, so the REST and gRPC layers
translate errors without knowing the individual classes, and the algorithm core stays free
of any web or RPC import (the codes are plain strings here).
"""

from __future__ import annotations

from typing import Any, ClassVar


class GridplaceError(Exception):
    """Base of every gridplace error."""

    code: ClassVar[str] = "internal_error"
    http_status: ClassVar[int] = 500
    grpc_status: ClassVar[str] = "INTERNAL"

    def __init__(self, message: str, **details: Any) -> None:
        super().__init__(message)
        self.message = message
        self.details = details

    def to_dict(self) -> dict[str, Any]:
        """A JSON-ready description used by the API layers and the CLI."""
        out: dict[str, Any] = {"error": self.code, "message": self.message}
        if self.details:
            out["details"] = self.details
        return out


class InvalidInputError(GridplaceError, ValueError):
    """The caller sent data that cannot be used (400 / INVALID_ARGUMENT)."""

    code = "invalid_input"
    http_status = 400
    grpc_status = "INVALID_ARGUMENT"


class NonFiniteInputError(InvalidInputError):
    code = "non_finite_input"


class DimensionMismatchError(InvalidInputError):
    code = "dimension_mismatch"


class EmptyInputError(InvalidInputError):
    code = "empty_input"


class InvalidParameterError(InvalidInputError):
    """A training or query parameter is out of its valid range."""

    code = "invalid_parameter"


class UnsafeFileError(InvalidInputError):
    """A file is not plain numeric data (pickled objects, wrong format, corrupt header)."""

    code = "unsafe_or_malformed_file"


class NotFittedError(GridplaceError, AttributeError):
    """A model was used before ``fit`` (409 / FAILED_PRECONDITION)."""

    code = "not_fitted"
    http_status = 409
    grpc_status = "FAILED_PRECONDITION"


class ArtifactError(GridplaceError):
    """A stored artifact is missing, corrupt, or of an unknown schema (DATA_LOSS)."""

    code = "artifact_error"
    http_status = 500
    grpc_status = "DATA_LOSS"


class NotFoundError(GridplaceError):
    code = "not_found"
    http_status = 404
    grpc_status = "NOT_FOUND"


class ConflictError(GridplaceError):
    """The request is valid but the target's state forbids it (409 / FAILED_PRECONDITION)."""

    code = "conflict"
    http_status = 409
    grpc_status = "FAILED_PRECONDITION"


class DimensionChangeError(ConflictError):
    """A new version would change a map's descriptor width (its clients would break) and the
    upload did not say ``allow_dimension_change``."""

    code = "dimension_change"


class PayloadTooLargeError(InvalidInputError):
    code = "payload_too_large"
    http_status = 413
    grpc_status = "RESOURCE_EXHAUSTED"


class UnauthorizedError(GridplaceError):
    code = "unauthorized"
    http_status = 401
    grpc_status = "UNAUTHENTICATED"


class ForbiddenError(GridplaceError):
    code = "forbidden"
    http_status = 403
    grpc_status = "PERMISSION_DENIED"


class UnavailableError(GridplaceError):
    code = "unavailable"
    http_status = 503
    grpc_status = "UNAVAILABLE"

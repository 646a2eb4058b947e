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


class InputOverflowError(NonFiniteInputError):
    """Finite values so far from the route's scale that they overflow once normalised."""

    code = "input_overflow"


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


class RequestValidationError(InvalidInputError):
    """A request that does not match the API's schema: a missing, unknown or mistyped field
    (422 / INVALID_ARGUMENT). Refusals that depend on the data (a descriptor of the wrong
    width for the map, a file that is not a .npy) are 400s of the other classes."""

    code = "validation_error"
    http_status = 422


class MethodNotAllowedError(InvalidInputError):
    code = "method_not_allowed"
    http_status = 405
    grpc_status = "UNIMPLEMENTED"


class UnsupportedMediaTypeError(InvalidInputError):
    code = "unsupported_media_type"
    http_status = 415


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


class NotFittedError(GridplaceError, AttributeError):
    """A model was used before ``fit`` (409 / FAILED_PRECONDITION)."""

    code = "not_fitted"
    http_status = 409
    grpc_status = "FAILED_PRECONDITION"


class DimensionChangeError(ConflictError):
    """A new version would change a map's descriptor width (its clients would break) and the
    upload did not say ``allow_dimension_change``."""

    code = "dimension_change"


class RetrainRequiredError(ConflictError):
    """An append or extension cannot keep the map's existing labels (its code's periods do not
    tell the extended route's places apart): the map needs a full retrain."""

    code = "retrain_required"


class PayloadTooLargeError(InvalidInputError):
    code = "payload_too_large"
    http_status = 413
    grpc_status = "RESOURCE_EXHAUSTED"


class CancelledError(GridplaceError):
    """The caller went away before its answer, and its work was stopped (nginx's 499: no one
    reads the answer)."""

    code = "cancelled"
    http_status = 499
    grpc_status = "CANCELLED"


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


class CapacityError(UnavailableError):
    """The server already holds as much of something as its settings allow (open streams,
    vehicle state): nothing is wrong with the request, retry later."""

    code = "capacity_exhausted"
    grpc_status = "RESOURCE_EXHAUSTED"


def _known() -> list[type[GridplaceError]]:
    """The classes of this module, breadth-first (a base class before its subclasses)."""
    out: list[type[GridplaceError]] = [GridplaceError]
    i = 0
    while i < len(out):
        out.extend(
            sub for sub in out[i].__subclasses__() if sub.__module__ == __name__ and sub not in out
        )
        i += 1
    return out


def error_class(code: str | None, http_status: int) -> type[GridplaceError]:
    """The class of an error answer: the one with this ``code`` (and this HTTP status, where
    several share a code), else the most general class of ``http_status``, else by range.
    Only this module's classes answer: subclasses raised elsewhere share their base's code."""
    known = _known()
    same_code = [c for c in known if c.code == code]
    for cls in same_code:
        if cls.http_status == http_status:
            return cls
    if same_code:
        return same_code[0]
    by_status = [c for c in known if c.http_status == http_status]
    if by_status:
        return by_status[0]  # breadth-first: the base class of that status comes first
    return InvalidInputError if 400 <= http_status < 500 else GridplaceError

"""The error body of every failed request: ``{"error": code, "message": …, "details": …}``.

``error`` is the ``code`` of a class of :mod:`service.errors` (``dimension_mismatch``,
``not_found``, ``validation_error``…); :func:`service.errors.error_class` maps it back.
"""

from __future__ import annotations

from typing import Any

from pydantic import Field

from service.wire.base import Answer


class ErrorBody(Answer):
    error: str = Field(description="machine-readable code, e.g. dimension_mismatch")
    message: str = Field(description="what went wrong, for a person")
    details: dict[str, Any] | None = Field(None, description="the values the message names")

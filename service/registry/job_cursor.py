"""The opaque cursor of the newest-first job listing: a job's ``(created_at, id)``, encoded
so a client passes it back unread to get the next page."""

from __future__ import annotations

import base64
import json

from service.errors import InvalidInputError
from service.registry.db import from_text, to_text
from service.registry.models import JobInfo

MAX_CURSOR_CHARS = 256  # a cursor of encode_cursor is about 100


def encode_cursor(job: JobInfo) -> str:
    """An opaque position after ``job`` in the newest-first job listing."""
    raw = json.dumps([to_text(job.created_at), job.id]).encode()
    return base64.urlsafe_b64encode(raw).decode().rstrip("=")


def decode_cursor(cursor: str) -> tuple[str, str]:
    """The position a cursor of :func:`encode_cursor` names; anything else (too long, nested,
    holding a NUL, which PostgreSQL's text cannot) is invalid input."""
    shown = cursor[:80] + ("…" if len(cursor) > 80 else "")
    try:
        if len(cursor) > MAX_CURSOR_CHARS:
            raise ValueError(f"longer than {MAX_CURSOR_CHARS} characters")
        raw = base64.urlsafe_b64decode(cursor + "=" * (-len(cursor) % 4))
        if raw[:1] != b"[" or raw.count(b"[") != 1:
            raise ValueError("not a position")
        created_at, job_id = json.loads(raw)
        if not isinstance(created_at, str) or not isinstance(job_id, str):
            raise ValueError(cursor)
        if "\x00" in created_at or "\x00" in job_id:
            raise ValueError("holds a NUL")
        from_text(created_at)
    except (ValueError, TypeError, RecursionError) as exc:
        raise InvalidInputError(f"invalid job list cursor {shown!r}", cursor=shown) from exc
    return created_at, job_id

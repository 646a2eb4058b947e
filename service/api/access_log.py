"""Keep credentials out of the access log.

uvicorn logs every request line with its query string. A caller may put a token there under
any name (it is refused: the admin API reads only ``Authorization``), so the line would store
a secret in the log. This filter drops the query string of every admin path and, on all
others, logs only the parameters of an allow-list (those the public API documents: the map,
the descriptor size, adaptation, the condition and the sequence filter's options) with their values; every
other parameter is logged as ``***``, name and value.
"""

from __future__ import annotations

import logging
from urllib.parse import parse_qsl, urlencode

from service.wire import SequenceFilterOptions

ACCESS_LOGGER = "uvicorn.access"
LOGGED_PARAMS = frozenset({"map", "d", "adaptation", "condition", *SequenceFilterOptions.model_fields})
HIDDEN = "***"


def scrub_path(path: str, admin_prefixes: tuple[str, ...]) -> str:
    """``path`` as it may be logged."""
    base, sep, query = path.partition("?")
    if not sep:
        return path
    if base.startswith(admin_prefixes):
        return base
    pairs = parse_qsl(query, keep_blank_values=True)
    shown = [urlencode([(k, v)]) if k in LOGGED_PARAMS else HIDDEN for k, v in pairs]
    return f"{base}?{'&'.join(shown)}" if shown else base


class CredentialFilter(logging.Filter):
    """Rewrites uvicorn access records (args: client, method, path, http version, status)."""

    def __init__(self, admin_prefixes: tuple[str, ...]) -> None:
        super().__init__("gridplace-credentials")
        self.admin_prefixes = admin_prefixes

    def filter(self, record: logging.LogRecord) -> bool:
        args = record.args
        if isinstance(args, tuple) and len(args) >= 3 and isinstance(args[2], str):
            record.args = (*args[:2], scrub_path(args[2], self.admin_prefixes), *args[3:])
        return True


def install(admin_prefixes: tuple[str, ...]) -> None:
    """Add the filter to uvicorn's access logger (once per process)."""
    logger = logging.getLogger(ACCESS_LOGGER)
    if not any(isinstance(f, CredentialFilter) for f in logger.filters):
        logger.addFilter(CredentialFilter(admin_prefixes))

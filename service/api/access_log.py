"""Keep credentials out of the access log.

uvicorn logs every request line with its query string. A caller may put a token there (it is
refused: the admin API reads only ``Authorization``), so the line would store a secret in the
log. This filter drops the query string of every admin path and masks credential-like
parameters (``token``, ``access_token``, ``api_key``…) on all others.
"""

from __future__ import annotations

import logging
from urllib.parse import parse_qsl, urlencode

ACCESS_LOGGER = "uvicorn.access"
SECRET_PARAMS = frozenset({"token", "access_token", "id_token", "refresh_token", "api_key",
                           "apikey", "key", "secret", "password", "auth", "authorization",
                           "bearer", "session", "signature", "sig"})  # fmt: skip


def scrub_path(path: str, admin_prefixes: tuple[str, ...]) -> str:
    """``path`` as it may be logged."""
    base, sep, query = path.partition("?")
    if not sep:
        return path
    if base.startswith(admin_prefixes):
        return base
    pairs = parse_qsl(query, keep_blank_values=True)
    masked = [(k, "***" if k.lower() in SECRET_PARAMS else v) for k, v in pairs]
    return f"{base}?{urlencode(masked, safe='*')}"


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

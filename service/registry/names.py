"""Validation of map names and version numbers (they become directory names on disk)."""

from __future__ import annotations

import re

from service.errors import InvalidInputError
from service.wire import MAP_NAME_PATTERN, MAX_VERSION

_MAP_NAME = re.compile(MAP_NAME_PATTERN)


def check_map_name(name: object) -> str:
    """``name`` if it is a valid map name, else :class:`InvalidInputError`."""
    if not isinstance(name, str) or not _MAP_NAME.fullmatch(name):
        raise InvalidInputError(
            f"invalid map name {name!r}: 1-64 characters of lower-case letters, digits, "
            "'_', '-' and '.', starting with a letter or digit",
            pattern=MAP_NAME_PATTERN,
        )
    return name


def check_version(version: object) -> int:
    """``version`` as an int if it is an integer in [1, 2^63 − 1], else
    :class:`InvalidInputError`."""
    if isinstance(version, bool) or not isinstance(version, int) or not 1 <= version <= MAX_VERSION:
        raise InvalidInputError(
            f"invalid version {version!r}: versions are integers from 1 to {MAX_VERSION}"
        )
    return version

"""Folders and files a command writes: a missing folder is made; one that cannot be (a file in
the way, no permission) is refused before any work, as a clear error (exit 2)."""

from __future__ import annotations

from pathlib import Path

from service.errors import InvalidParameterError


def writable_dir(path: Path | None, option: str) -> Path | None:
    """``path`` made if missing (``None``: the system's temporary folder, left to the caller)."""
    if path is None:
        return None
    try:
        path.mkdir(parents=True, exist_ok=True)
    except FileExistsError as exc:
        raise InvalidParameterError(f"{option} {path}: not a folder") from exc
    except OSError as exc:
        raise InvalidParameterError(f"{option} {path}: cannot be made ({exc.strerror})") from exc
    return path


def output_file(path: Path, option: str) -> Path:
    """``path``'s folder made if missing; ``path`` itself must not be a folder."""
    if path.is_dir():
        raise InvalidParameterError(f"{option} {path}: a folder, not a file")
    writable_dir(path.parent, option)
    return path

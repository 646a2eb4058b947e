"""Parsing route uploads safely and storing their descriptors atomically.

Accepted: ``.npy``/``.npz`` (numeric, never unpickled) and ``.zip``/``.tar[.gz|.bz2|.xz]``
archives of images, taken in file-name order and turned into descriptors by the configured
extractor. Archives are checked against the upload limit on their declared *and* actual
decompressed sizes, and on their number of members (zip bombs, tar bombs).
"""

from __future__ import annotations

import hashlib
import os
import tarfile
import tempfile
import zipfile
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import IO

import numpy as np

from service.core.array_upload import read_npy_descriptors, read_npz_descriptors
from service.encoding import check_descriptors
from service.errors import EmptyInputError, PayloadTooLargeError, UnsafeFileError
from service.imaging import Extractor, extract_blobs, is_image_name
from service.npyfile import describe

MAX_MEMBERS = 1_000_000
MAX_RATIO = 1000  # zip: declared size / compressed size above this is refused as a bomb
_CHUNK = 1 << 20
RouteCheck = Callable[[int, int], None]  # (n_frames, n_features) → raises if unusable


@dataclass(frozen=True)
class StoredRoute:
    path: Path  # data_dir/uploads/<sha256>.npy
    sha256: str
    n_frames: int
    n_features: int
    source_kind: str  # "npy" | "images"


def sniff_kind(filename: str, head: bytes) -> str:
    """``npy``, ``zip`` or ``tar`` from magic bytes (file name as a tie-breaker)."""
    if head.startswith(b"\x93NUMPY"):
        return "npy"
    if head.startswith((b"PK\x03\x04", b"PK\x05\x06")):
        name = filename.lower()
        return "npy" if name.endswith(".npz") else "zip"
    if head[:2] == b"\x1f\x8b" or head[:3] == b"BZh" or head[:6] == b"\xfd7zXZ\x00":
        return "tar"
    if len(head) > 262 and head[257:262] == b"ustar":
        return "tar"
    if not head:
        raise EmptyInputError(f"the upload {filename!r} is empty (0 bytes)")
    raise UnsafeFileError(
        f"the upload {filename!r} is neither .npy/.npz descriptors nor a .zip/.tar of images: "
        f"it looks like {describe(head)}"
    )


def _zip_members(fh: IO[bytes], limit: int) -> Iterator[tuple[str, bytes]]:
    try:
        zf = zipfile.ZipFile(fh)
    except (zipfile.BadZipFile, OSError, ValueError) as exc:
        raise UnsafeFileError(f"not a valid zip archive: {exc}") from exc
    infos = [i for i in zf.infolist() if not i.is_dir() and is_image_name(i.filename)]
    if len(zf.infolist()) > MAX_MEMBERS:
        raise PayloadTooLargeError(f"the zip archive has more than {MAX_MEMBERS} members")
    declared = sum(i.file_size for i in infos)
    if declared > limit:
        raise PayloadTooLargeError(
            f"the zip archive declares {declared} bytes of images once decompressed, "
            f"more than the {limit}-byte upload limit",
            declared_bytes=declared, limit_bytes=limit,
        )  # fmt: skip
    for i in infos:
        if i.compress_size and i.file_size / i.compress_size > MAX_RATIO:
            raise PayloadTooLargeError(
                f"zip member {i.filename!r} expands {i.file_size / i.compress_size:.0f}-fold; "
                "refused as a decompression bomb"
            )
    total = 0
    for info in sorted(infos, key=lambda i: i.filename):
        buf = bytearray()
        try:
            with zf.open(info) as member:
                while chunk := member.read(_CHUNK):
                    buf += chunk
                    total += len(chunk)
                    if len(buf) > info.file_size or total > limit:
                        raise PayloadTooLargeError(
                            f"zip member {info.filename!r} decompresses beyond its declared "
                            f"size or the {limit}-byte upload limit"
                        )
        except (zipfile.BadZipFile, OSError, EOFError, NotImplementedError) as exc:
            raise UnsafeFileError(f"corrupt zip member {info.filename!r}: {exc}") from exc
        yield info.filename, bytes(buf)


def _tar_members(fh: IO[bytes], limit: int) -> Iterator[tuple[str, bytes]]:
    try:
        tf = tarfile.open(fileobj=fh, mode="r:*")  # noqa: SIM115 - read lazily below; fh owns the data
        members = []
        for count, m in enumerate(tf, 1):
            if count > MAX_MEMBERS:
                raise PayloadTooLargeError(f"the tar archive has more than {MAX_MEMBERS} members")
            if m.isfile() and is_image_name(m.name):
                members.append(m)
    except (tarfile.TarError, OSError, EOFError) as exc:
        raise UnsafeFileError(f"not a valid tar archive: {exc}") from exc
    declared = sum(m.size for m in members)
    if declared > limit:
        raise PayloadTooLargeError(
            f"the tar archive holds {declared} bytes of images, more than the "
            f"{limit}-byte upload limit", declared_bytes=declared, limit_bytes=limit,
        )  # fmt: skip
    for m in sorted(members, key=lambda m: m.name):
        try:
            src = tf.extractfile(m)
            data = src.read(m.size + 1) if src is not None else b""
        except (tarfile.TarError, OSError, EOFError) as exc:
            raise UnsafeFileError(f"corrupt tar member {m.name!r}: {exc}") from exc
        if len(data) > m.size:
            raise UnsafeFileError(f"tar member {m.name!r} is longer than declared")
        yield m.name, data


def _count_images(kind: str, fh: IO[bytes]) -> int:
    fh.seek(0)
    if kind == "zip":
        try:
            return sum(
                1 for i in zipfile.ZipFile(fh).infolist()
                if not i.is_dir() and is_image_name(i.filename)
            )  # fmt: skip
        except (zipfile.BadZipFile, OSError, ValueError) as exc:
            raise UnsafeFileError(f"not a valid zip archive: {exc}") from exc
    try:
        with tarfile.open(fileobj=fh, mode="r:*") as tf:
            return sum(1 for m in tf if m.isfile() and is_image_name(m.name))
    except (tarfile.TarError, OSError, EOFError) as exc:
        raise UnsafeFileError(f"not a valid tar archive: {exc}") from exc


def parse_route(
    filename: str,
    fh: IO[bytes],
    limit_bytes: int,
    extractor_factory: Callable[[], Extractor],
    check: RouteCheck | None = None,
    image_features: int | None = None,
) -> tuple[np.ndarray, str]:
    """The route's float32 ``(N, d)`` descriptors and ``"npy"`` or ``"images"``.

    ``check(N, d)`` runs as soon as the shape is known and before the data is read: from the
    ``.npy`` header, or from an archive's image count and ``image_features`` (the extractor's
    d), so parameters that cannot fit the route are refused without decoding anything."""
    fh.seek(0)
    head = fh.read(512)
    kind = sniff_kind(filename, head)
    fh.seek(0)
    if kind == "npy":
        what = f"descriptors in {filename!r}"
        if head.startswith(b"\x93NUMPY"):
            return read_npy_descriptors(fh, what, limit_bytes, check=check), "npy"
        return read_npz_descriptors(fh, what, limit_bytes, check=check), "npy"
    n = _count_images(kind, fh)
    if n == 0:
        raise EmptyInputError(f"the archive {filename!r} contains no image files")
    fh.seek(0)
    members = _zip_members(fh, limit_bytes) if kind == "zip" else _tar_members(fh, limit_bytes)
    first = next(members)  # validate sizes before building a (possibly heavy) extractor
    if check is not None and image_features is not None and n >= 2:
        check(n, image_features)  # before decoding a single image
    extractor = extractor_factory()

    def chain() -> Iterator[tuple[str, bytes]]:
        yield first
        yield from members

    X = extract_blobs(extractor, chain(), n)
    arr = check_descriptors(X, min_rows=2, what=f"image descriptors of {filename!r}")
    return arr.astype(np.float32), "images"


class _HashingWriter:
    """A write-only file that hashes what passes through it (``np.save`` writes in blocks)."""

    def __init__(self, out: IO[bytes]) -> None:
        self.out = out
        self.sha = hashlib.sha256()

    def write(self, data: bytes) -> int:
        self.sha.update(data)
        return self.out.write(data)


def relative_to(path: Path, data_dir: Path) -> str:
    """``path`` relative to ``data_dir`` when inside it (a job's files move with it)."""
    try:
        return str(path.resolve().relative_to(data_dir.resolve()))
    except ValueError:
        return str(path.resolve())


def store_descriptors(data_dir: Path, X: np.ndarray, source_kind: str) -> StoredRoute:
    """Write ``X`` to ``data_dir/uploads/<sha256 of the .npy>.npy`` atomically (tmp, fsync,
    rename), streamed and hashed on the way: no copy of the route is made in memory."""
    final, sha, _ = store_array(data_dir, X, np.float32)
    return StoredRoute(final, sha, int(X.shape[0]), int(X.shape[1]), source_kind)


def store_array(data_dir: Path, X: np.ndarray, dtype: type[np.generic]) -> tuple[Path, str, bool]:
    """Write ``X`` as ``dtype`` to ``data_dir/uploads/<sha256 of the .npy>.npy`` atomically;
    returns the path, the sha256 and whether this call created the file (an identical upload
    may have stored it before)."""
    folder = data_dir / "uploads"
    folder.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=folder, prefix=".upload-", suffix=".tmp")
    created = False
    try:
        with os.fdopen(fd, "wb") as out:
            writer = _HashingWriter(out)
            np.save(writer, np.ascontiguousarray(X, dtype=dtype), allow_pickle=False)  # type: ignore[arg-type]
            out.flush()
            os.fsync(out.fileno())
        sha = writer.sha.hexdigest()
        final = folder / f"{sha}.npy"
        if final.exists():
            Path(tmp).unlink()
        else:
            os.replace(tmp, final)
            created = True
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    dfd = os.open(folder, os.O_RDONLY)
    try:
        os.fsync(dfd)
    finally:
        os.close(dfd)
    return final, sha, created

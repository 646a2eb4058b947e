"""Reading ``.npy`` / ``.npz`` descriptor files safely (numpy and the standard library only).

Nothing is ever unpickled. A file is identified by its magic bytes first, so a CSV, an image
or a pickle is named as what it is rather than reported as "pickled objects"; the header is
parsed before any data is read, so a caller can check the declared shape and dtype (against
a size limit, or the training parameters) before anything is allocated. The client, the CLI
and the server all read descriptor files through :func:`load_npy`.
"""

from __future__ import annotations

import io
import math
import os
import zipfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import IO

import numpy as np

from service.errors import EmptyInputError, InvalidInputError, UnsafeFileError

NPY_MAGIC = b"\x93NUMPY"
ZIP_MAGICS = (b"PK\x03\x04", b"PK\x05\x06")
NUMERIC_KINDS = "biuf"


@dataclass(frozen=True)
class NpyHeader:
    """What a ``.npy`` header declares."""

    shape: tuple[int, ...]
    dtype: np.dtype
    fortran_order: bool

    @property
    def nbytes(self) -> int:
        return math.prod(self.shape) * self.dtype.itemsize


HeaderCheck = Callable[[NpyHeader], None]


def describe(head: bytes) -> str:
    """What a file that is not ``.npy``/``.npz`` looks like, from its first bytes."""
    if not head:
        return "an empty file"
    if head[:1] == b"\x80" and len(head) > 1 and head[1] <= 5:
        return "a Python pickle"
    if head.startswith((b"\x89PNG", b"\xff\xd8\xff", b"GIF8", b"BM", b"RIFF")):
        return "an image"
    if head[:2] == b"\x1f\x8b" or head[:3] == b"BZh" or head[:6] == b"\xfd7zXZ\x00":
        return "a compressed file (gzip, bzip2 or xz)"
    try:
        text = head.decode("utf-8")
    except UnicodeDecodeError:
        return "binary data of an unknown format"
    if all(c.isprintable() or c in "\r\n\t" for c in text):
        if any(sep in text for sep in ",;\t") and any(c.isdigit() for c in text):
            return ("text with delimited numbers (CSV?); convert it with "
                    "numpy.save('x.npy', numpy.loadtxt(path, delimiter=','))")  # fmt: skip
        return "a text file"
    return "binary data of an unknown format"


# file names the image extractors read (service.imaging.files lists folders with them)
IMAGE_SUFFIXES = frozenset({".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".webp", ".gif",
                            ".pgm", ".ppm"})  # fmt: skip


def _folder_message(path: Path) -> str:
    """Why a folder is not a descriptor file, and, for a folder of images, what makes one."""
    try:
        images = sum(1 for p in path.iterdir()
                     if not p.name.startswith(".") and p.suffix.lower() in IMAGE_SUFFIXES)  # fmt: skip
    except OSError:
        images = 0
    if not images:
        return f"{path} is a folder, not a .npy file of descriptors"
    return (f"{path} is a folder of {images:,} image{'s' if images != 1 else ''}, not a .npy file "
            f"of descriptors: make one with `gridplace extract {path} --out descriptors.npy` "
            "(the extractor the server uses)")  # fmt: skip


def check_numeric(dtype: np.dtype, what: str) -> None:
    """Refuse object arrays (pickled Python objects) and any non-numeric dtype."""
    if dtype.hasobject:
        raise UnsafeFileError(
            f"{what} holds pickled Python objects (dtype {dtype}); only numeric arrays are "
            "accepted"
        )
    if dtype.kind not in NUMERIC_KINDS or dtype.names is not None or dtype.subdtype is not None:
        raise UnsafeFileError(
            f"{what} must hold a numeric array (bool, int or float), got dtype {dtype}"
        )


def read_header(fh: IO[bytes], what: str) -> NpyHeader:
    """The header of the ``.npy`` stream at ``fh`` (positioned at its magic)."""
    try:
        version = np.lib.format.read_magic(fh)
        readers = {(1, 0): np.lib.format.read_array_header_1_0,
                   (2, 0): np.lib.format.read_array_header_2_0}  # fmt: skip
        reader = readers.get(version)
        if reader is not None:
            shape, fortran, dtype = reader(fh)
    except Exception as exc:  # noqa: BLE001 - numpy parses the header with ast/tokenize: any error
        raise UnsafeFileError(f"{what} is not a valid .npy file: corrupt header: {exc}") from exc
    if reader is None:
        raise UnsafeFileError(
            f"{what} is not a valid .npy file: unsupported format version {version}"
        )
    return NpyHeader(tuple(int(n) for n in shape), np.dtype(dtype), bool(fortran))


def _read_npy(fh: IO[bytes], what: str, check: HeaderCheck | None) -> np.ndarray:
    header = read_header(fh, what)
    check_numeric(header.dtype, what)
    if check is not None:
        check(header)
    flat = np.empty(math.prod(header.shape), dtype=header.dtype)
    buf = memoryview(flat).cast("B")
    got = 0
    try:
        while got < len(buf) and (n := fh.readinto(buf[got:])):  # type: ignore[attr-defined]
            got += n
    except (OSError, EOFError, zipfile.BadZipFile) as exc:
        raise UnsafeFileError(f"{what} cannot be read: {exc}") from exc
    if got < len(buf):
        raise UnsafeFileError(
            f"{what} is truncated: its header declares shape {header.shape} of {header.dtype} "
            f"({header.nbytes} bytes of data) but {got} bytes follow",
            declared_bytes=header.nbytes, got_bytes=got,
        )  # fmt: skip
    return flat.reshape(header.shape, order="F" if header.fortran_order else "C")


def _read_npz(fh: IO[bytes], what: str, check: HeaderCheck | None) -> np.ndarray:
    try:
        with zipfile.ZipFile(fh) as zf:
            members = [n for n in zf.namelist() if n.endswith(".npy")]
            if not members:
                raise EmptyInputError(f"{what}: the .npz archive holds no array")
            name = "descriptors.npy" if "descriptors.npy" in members else members[0]
            with zf.open(name) as member:
                return _read_npy(member, f"{what} (array {name[:-4]!r})", check)
    except (zipfile.BadZipFile, zipfile.LargeZipFile, NotImplementedError) as exc:
        raise UnsafeFileError(f"{what} is not a valid .npz archive: {exc}") from exc


def load_npy(
    source: str | os.PathLike[str] | bytes,
    *,
    what: str | None = None,
    check: HeaderCheck | None = None,
) -> np.ndarray:
    """The numeric array of a ``.npy`` file (or the ``descriptors``/first array of an ``.npz``).

    ``check`` sees the header (shape, dtype) before any data is read and may raise.
    """
    if isinstance(source, bytes):
        name = what or "the file"
        fh: IO[bytes] = io.BytesIO(source)
    else:
        path = Path(source)
        name = what or str(path)
        if path.is_dir():
            raise InvalidInputError(_folder_message(path), path=str(path))
        if not path.is_file():
            raise InvalidInputError(f"no such file: {path}", path=str(path))
        fh = path.open("rb")
    with fh:
        head = fh.read(8)
        fh.seek(0)
        if head.startswith(NPY_MAGIC):
            return _read_npy(fh, name, check)
        if head.startswith(ZIP_MAGICS):
            return _read_npz(fh, name, check)
        if not head:
            raise EmptyInputError(f"{name} is empty (0 bytes)")
        raise UnsafeFileError(f"{name} is not a .npy file: it looks like {describe(fh.read(512))}")

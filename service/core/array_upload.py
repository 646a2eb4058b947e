"""Uploaded ``.npy``/``.npz`` descriptors read within a memory budget, never unpickled.

The array's header is read first: its dtype must be plain numeric and its declared shape is
checked against the bytes the file (or the archive member) really holds and against the
budget *as float32 descriptors* (what the route becomes: a uint8 array grows 4-fold) before a
single byte is allocated. The data is then streamed, block by block, straight into the float32
result, each block checked for NaN, infinity and values beyond float32's range, so memory peaks
at the result plus one block: never a second copy, never a decompressed member in full. Of an
``.npz`` only the ``descriptors`` member (else the first ``.npy`` member) is decompressed.
"""

from __future__ import annotations

import io
import zipfile
from collections.abc import Callable
from typing import IO

import numpy as np

from service.errors import (
    DimensionMismatchError,
    EmptyInputError,
    InvalidInputError,
    NonFiniteInputError,
    PayloadTooLargeError,
    UnsafeFileError,
)
from service.npyfile import check_numeric, read_header

BLOCK_BYTES = 1 << 20
ShapeCheck = Callable[[int, int], None]  # (rows, columns) → raises if the route is unusable


def read_npy_descriptors(fh: IO[bytes], what: str, budget_bytes: int, size: int | None = None,
                         min_rows: int = 2, check: ShapeCheck | None = None) -> np.ndarray:  # fmt: skip
    """``(N, d)`` float32 descriptors from a ``.npy`` stream positioned at its start.

    ``size``: the bytes the stream holds (None: measured by seeking to its end). ``check``
    sees the declared shape once it is known to be within budget and present, before any
    data is read."""
    if size is None:
        start = fh.tell()
        size = fh.seek(0, io.SEEK_END) - start
        fh.seek(start)
    header = read_header(fh, what)
    shape, fortran, dtype = header.shape, header.fortran_order, header.dtype
    rows, cols = _check_header(what, shape, dtype, min_rows)
    declared = rows * cols * dtype.itemsize
    as_float32 = rows * cols * 4
    if as_float32 > budget_bytes or declared > budget_bytes:
        raise PayloadTooLargeError(
            f"{what} declares a {rows}×{cols} {dtype} array: {max(as_float32, declared)} bytes "
            f"as float32 descriptors, more than the {budget_bytes}-byte upload limit "
            "(GRIDPLACE_MAX_UPLOAD_MB)", declared_bytes=max(as_float32, declared),
            limit_bytes=budget_bytes,
        )  # fmt: skip
    held = max(0, size - fh.tell())
    if held < declared:
        raise UnsafeFileError(
            f"{what} is truncated: its header declares a {rows}×{cols} {dtype} array "
            f"({declared} bytes) but the file holds {held} bytes of data",
            declared_bytes=declared, data_bytes=held,
        )  # fmt: skip
    if check is not None:
        check(rows, cols)
    return _stream_into_float32(fh, what, rows, cols, dtype, fortran)


def _check_header(what: str, shape: tuple[int, ...], dtype: np.dtype, min_rows: int) -> tuple[int, int]:
    check_numeric(dtype, what)
    if len(shape) != 2:
        raise DimensionMismatchError(
            f"{what}: must be a 2-D array (rows = frames), got {len(shape)} dimension(s)",
            shape=list(shape),
        )  # fmt: skip
    rows, cols = int(shape[0]), int(shape[1])
    if rows < 0 or cols < 0:
        raise UnsafeFileError(f"{what}: the header declares a negative dimension {tuple(shape)}")
    if rows == 0 or cols == 0:
        raise EmptyInputError(f"{what}: empty (shape {tuple(shape)})")
    if rows < min_rows:
        raise InvalidInputError(f"{what}: at least {min_rows} rows needed, got {rows}", rows=rows)
    return rows, cols


def _read_exact(fh: IO[bytes], n: int, what: str) -> bytes:
    data = fh.read(n)
    if len(data) != n:
        raise UnsafeFileError(f"{what} is truncated: the data ends before its declared size")
    return data


def _stream_into_float32(fh: IO[bytes], what: str, rows: int, cols: int, dtype: np.dtype,
                         fortran: bool) -> np.ndarray:  # fmt: skip
    """Copy the data into a C-ordered float32 array one block of stored lines at a time
    (rows of a C-ordered array, columns of a Fortran-ordered one)."""
    out = np.empty((rows, cols), dtype=np.float32)
    lines, line_len = (cols, rows) if fortran else (rows, cols)
    step = max(1, BLOCK_BYTES // (line_len * dtype.itemsize))
    for first in range(0, lines, step):
        n = min(step, lines - first)
        raw = np.frombuffer(_read_exact(fh, n * line_len * dtype.itemsize, what), dtype=dtype)
        with np.errstate(over="ignore", invalid="ignore"):
            block = raw.reshape(n, line_len).astype(np.float32)
        bad = ~np.isfinite(block)
        if bad.any():
            i, j = (int(v) for v in np.argwhere(bad)[0])
            row, column = (j, first + i) if fortran else (first + i, j)
            raise NonFiniteInputError(
                f"{what}: NaN, infinite or beyond-float32 values (first at row {row}, "
                f"column {column})", row=row, column=column,
            )  # fmt: skip
        if fortran:
            out[:, first : first + n] = block.T
        else:
            out[first : first + n] = block
    return out


def read_npz_descriptors(fh: IO[bytes], what: str, budget_bytes: int, min_rows: int = 2,
                         check: ShapeCheck | None = None) -> np.ndarray:  # fmt: skip
    """``(N, d)`` float32 descriptors of an ``.npz``'s ``descriptors`` (else first) array."""
    try:
        zf = zipfile.ZipFile(fh)
    except (zipfile.BadZipFile, OSError, ValueError) as exc:
        raise UnsafeFileError(f"{what} is not a valid .npz archive: {exc}") from exc
    with zf:
        members = [i for i in zf.infolist() if not i.is_dir() and i.filename.endswith(".npy")]
        if not members:
            raise EmptyInputError(f"the .npz archive {what} holds no array")
        info = next((i for i in members if i.filename == "descriptors.npy"), members[0])
        label = f"{what}[{info.filename[:-4]}]"
        try:
            with zf.open(info) as member:  # decompresses lazily, never beyond file_size
                return read_npy_descriptors(member, label, budget_bytes, size=info.file_size,
                                            min_rows=min_rows, check=check)  # fmt: skip
        except (zipfile.BadZipFile, OSError, EOFError, NotImplementedError, RuntimeError) as exc:
            raise UnsafeFileError(f"{label} is a corrupt archive member: {exc}") from exc

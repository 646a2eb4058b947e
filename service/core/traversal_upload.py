"""A route upload of several traversals: one descriptor file (or image archive) per traversal
and optionally one place-index file per traversal.

Every file is checked as soon as its shape is known (its ``.npy`` header or image count):
its width against the first file's (and the extractor's and the map's), and without place
indices its length against the first file's, before its data is read. The traversals are
then validated together (:func:`service.encoding.traversals.as_traversals`) and stored only
when all of them are usable: the stacked float32 descriptors and the int64 place of every
row, each content-addressed under ``uploads/``. The upload's content hash covers both (and
the number of traversals), so the same traversals uploaded again are recognised.
"""

from __future__ import annotations

import hashlib
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import IO

import numpy as np

from service.core.uploads import parse_route, store_array, store_descriptors
from service.encoding.traversals import Traversals, as_traversals
from service.errors import DimensionMismatchError, InvalidInputError, PayloadTooLargeError
from service.imaging import Extractor
from service.npyfile import NpyHeader, load_npy

WidthCheck = Callable[[int], None]  # n_features → raises if the map or extractor refuses it
ParamsCheck = Callable[[int, int], None]  # (n_places, n_features) → raises if unusable


@dataclass(frozen=True)
class UploadedFile:
    name: str
    fh: IO[bytes]


@dataclass(frozen=True)
class StoredTraversals:
    route: Path  # stacked float32 descriptors, data_dir/uploads/<sha256>.npy
    places: Path | None  # int64 place of every row; None: one traversal, row i is place i
    content_sha256: str  # of everything uploaded
    n_places: int
    n_features: int
    n_traversals: int
    source_kind: str  # "npy" | "images"


def check_file_counts(files: Sequence[UploadedFile], places: Sequence[UploadedFile],
                      what: str) -> None:  # fmt: skip
    """At least one ``file`` field, and one ``places`` file per file when any is sent;
    ``what`` names the files in the message (``"route"``, ``"traversal"``)."""
    if not files:
        raise InvalidInputError(f"send the {what} as one or more 'file' fields")
    if places and len(places) != len(files):
        raise InvalidInputError(
            f"{len(files)} {what} file(s) need {len(files)} 'places' file(s) (one per file, in "
            f"the same order), got {len(places)}", files=len(files), places=len(places),
        )  # fmt: skip


def parse_traversals(
    files: Sequence[UploadedFile],
    places: Sequence[UploadedFile],
    limit_bytes: int,
    extractor_factory: Callable[[], Extractor],
    check_width: WidthCheck,
    check_params: ParamsCheck,
    image_features: int | None = None,
) -> tuple[Traversals, str]:
    """The validated traversals of an upload and ``"npy"`` or ``"images"``; ``limit_bytes``
    bounds all files together (descriptors as float32)."""
    check_file_counts(files, places, "route")
    several = len(files) > 1
    first: list[tuple[int, int]] = []
    arrays: list[np.ndarray] = []
    kinds: set[str] = set()
    used = 0

    def label(i: int) -> str:
        return f"traversal {i + 1} ({files[i].name!r})"

    for i, upload in enumerate(files):

        def check(n_rows: int, n_features: int, i: int = i) -> None:
            if first and n_features != first[0][1]:
                raise DimensionMismatchError(
                    f"{label(i)} has {n_features} columns but {label(0)} has {first[0][1]}: "
                    "every traversal needs descriptors of one width",
                    traversal=i + 1, columns=n_features, expected=first[0][1],
                )  # fmt: skip
            if first and not places and n_rows != first[0][0]:
                raise DimensionMismatchError(
                    f"{label(i)} has {n_rows} rows but {label(0)} has {first[0][0]}: "
                    "traversals without place indices must be frame-aligned (one row per "
                    "place, same length); send one 'places' file per traversal otherwise",
                    traversal=i + 1, rows=n_rows, expected=first[0][0],
                )  # fmt: skip
            check_width(n_features)
            if not first:
                first.append((n_rows, n_features))
                if not places:
                    check_params(n_rows, n_features)

        remaining = limit_bytes - used
        if remaining <= 0:
            raise _too_large(limit_bytes, several)
        X, kind = parse_route(upload.name, upload.fh, remaining, extractor_factory, check,
                              image_features)  # fmt: skip
        if not first:  # an image archive of fewer than 2 frames skipped the early check
            check(*X.shape)
        used += X.nbytes
        arrays.append(X)
        kinds.add(kind)
    index = [read_places(p, arrays[i].shape[0], limit_bytes - used) for i, p in enumerate(places)]
    tr = as_traversals(arrays, index or None, keep_dtype=True,
                       names=[f.name for f in files])  # fmt: skip
    if places:
        check_params(tr.n_places, tr.n_features)
    return tr, "images" if "images" in kinds else "npy"


def _too_large(limit_bytes: int, several: bool) -> PayloadTooLargeError:
    what = "the route files together hold" if several else "the route holds"
    return PayloadTooLargeError(
        f"{what} more than the {limit_bytes}-byte upload limit as float32 descriptors "
        "(GRIDPLACE_MAX_UPLOAD_MB)", limit_bytes=limit_bytes,
    )  # fmt: skip


def read_places(upload: UploadedFile, n_rows: int, budget: int) -> np.ndarray:
    """One traversal's place index (a 1-D integer ``.npy``/``.npz``), its header checked
    against the traversal's rows before the data is read."""
    what = f"the place index {upload.name!r}"

    def check(header: NpyHeader) -> None:
        if len(header.shape) != 1 or header.shape[0] != n_rows:
            raise DimensionMismatchError(
                f"{what} has shape {list(header.shape)} but its traversal has {n_rows} rows: "
                "send one integer place per row", shape=list(header.shape), rows=n_rows,
            )  # fmt: skip
        if header.dtype.kind not in "iu":
            raise InvalidInputError(f"{what} must hold integers, got dtype {header.dtype}")

    data = upload.fh.read(max(0, budget) + 1)
    if len(data) > max(0, budget):
        raise PayloadTooLargeError(
            f"{what} is larger than what is left of the upload limit ({budget} bytes)",
            limit_bytes=budget,
        )  # fmt: skip
    return load_npy(data, what=what, check=check)


def store_traversals(data_dir: Path, tr: Traversals, source_kind: str) -> StoredTraversals:
    """Store validated traversals; the place index only when there is one (several
    traversals, or an uploaded index). Nothing is left behind if a write fails."""
    if tr.places is None:
        route = store_descriptors(data_dir, tr.rows, source_kind)
        return StoredTraversals(route.path, None, route.sha256, route.n_frames,
                                route.n_features, 1, source_kind)  # fmt: skip
    places, places_sha, created = store_array(data_dir, tr.places, np.int64)
    try:
        route = store_descriptors(data_dir, tr.rows, source_kind)
    except BaseException:
        if created:
            places.unlink(missing_ok=True)
        raise
    content = hashlib.sha256(
        f"gridplace-traversals:{tr.n_traversals}:{route.sha256}:{places_sha}".encode()
    ).hexdigest()
    return StoredTraversals(route.path, places, content, tr.n_places, tr.n_features,
                            tr.n_traversals, source_kind)  # fmt: skip

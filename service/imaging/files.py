"""Image folders → descriptor matrices, in file-name order, in batches."""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence
from pathlib import Path

import numpy as np

from service.errors import EmptyInputError, InvalidInputError
from service.npyfile import IMAGE_SUFFIXES
from service.imaging.decode import decode_batches
from service.imaging.extractors import Extractor

BATCH = 256


def is_image_name(name: str) -> bool:
    base = name.rsplit("/", 1)[-1]
    return not base.startswith(".") and Path(base).suffix.lower() in IMAGE_SUFFIXES


def list_images(folder: Path) -> list[Path]:
    """Image files directly in ``folder``, sorted by file name."""
    if not folder.is_dir():
        raise InvalidInputError(f"not a directory: {folder}")
    files = sorted((p for p in folder.iterdir() if p.is_file() and is_image_name(p.name)),
                   key=lambda p: p.name)  # fmt: skip
    if not files:
        raise EmptyInputError(f"no image files ({', '.join(sorted(IMAGE_SUFFIXES))}) in {folder}")
    return files


def extract_blobs(
    extractor: Extractor,
    blobs: Iterable[tuple[str, bytes]],
    total: int,
    progress: Callable[[int, int], None] | None = None,
) -> np.ndarray:
    """Descriptors of ``(name, bytes)`` images, decoded and extracted a batch at a time (at
    most ``extractor.batch_size`` images and :data:`~service.imaging.decode.BATCH_PIXELS`
    decoded pixels), so memory stays bounded and ``progress`` moves with every forward pass."""
    out = np.empty((total, extractor.n_features), dtype=np.float32)
    step = max(1, int(getattr(extractor, "batch_size", BATCH)))
    done = 0
    for batch in decode_batches(blobs, step):
        if done + len(batch) > total:
            raise InvalidInputError(f"expected {total} images, got more")
        out[done : done + len(batch)] = extractor.extract(batch)
        done += len(batch)
        if progress is not None:
            progress(done, total)
    if done != total:
        raise InvalidInputError(f"expected {total} images, decoded {done}")
    return out


def extract_paths(
    extractor: Extractor,
    paths: Sequence[Path],
    progress: Callable[[int, int], None] | None = None,
) -> np.ndarray:
    return extract_blobs(extractor, ((p.name, p.read_bytes()) for p in paths), len(paths), progress)

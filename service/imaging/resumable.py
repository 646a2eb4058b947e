"""Resumable extraction of an image folder into one ``.npy``.

Descriptors are written in chunks of ``chunk_rows`` frames to ``.<out>.partial/`` beside the
output, each chunk atomically (temp file, fsync, rename), under a manifest that names the
extractor config and fingerprints the file list. An interrupted run started again with the
same folder and config resumes after the last complete chunk; a different folder or config
starts over. The final array is assembled into a temp file and renamed into place, so ``out``
is either absent or complete, and the partial folder is removed.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO

import numpy as np

from service.durable import fsync_dir
from service.imaging.extractors import Extractor
from service.imaging.files import extract_paths

FORMAT = 1


@dataclass(frozen=True)
class FolderExtraction:
    out: Path
    n_frames: int
    n_features: int
    resumed_from: int  # frames found already extracted when this run started


def partial_dir(out: Path) -> Path:
    return out.with_name(f".{out.name}.partial")


def _fingerprint(paths: Sequence[Path]) -> str:
    h = hashlib.sha256()
    for p in paths:
        st = p.stat()
        h.update(f"{p.name}\0{st.st_size}\0{st.st_mtime_ns}\n".encode())
    return h.hexdigest()


def _write_atomic(path: Path, write: Callable[[BinaryIO], object]) -> None:
    tmp = path.with_name(f".{path.name}.tmp")
    with open(tmp, "wb") as fh:
        write(fh)
        fh.flush()
        os.fsync(fh.fileno())
    os.replace(tmp, path)
    fsync_dir(path.parent)


def _chunk_name(start: int) -> str:
    return f"rows-{start:010d}.npy"


def _done_chunks(work: Path, n: int, d: int, chunk_rows: int) -> int:
    """Frames covered by the complete chunks ``0, chunk_rows, …`` present in ``work``."""
    done = 0
    while done < n:
        path = work / _chunk_name(done)
        want = min(chunk_rows, n - done)
        try:
            arr = np.load(path, mmap_mode="r", allow_pickle=False)
        except (OSError, ValueError):
            break
        if arr.shape != (want, d) or arr.dtype != np.float32:
            break
        done += want
    return done


def extract_folder(
    extractor: Extractor,
    paths: Sequence[Path],
    out: Path,
    chunk_rows: int = 1024,
    progress: Callable[[int, int], None] | None = None,
    restart: bool = False,
) -> FolderExtraction:
    """Descriptors of ``paths`` (in that order) written to ``out``, resuming a partial run."""
    n, d = len(paths), extractor.n_features
    out.parent.mkdir(parents=True, exist_ok=True)
    work = partial_dir(out)
    manifest = {
        "format": FORMAT, "extractor": extractor.config.model_dump(mode="json"),
        "files": _fingerprint(paths), "n_frames": n, "n_features": d, "chunk_rows": chunk_rows,
    }  # fmt: skip
    stored = None
    if not restart and (work / "manifest.json").is_file():
        try:
            stored = json.loads((work / "manifest.json").read_text())
        except (OSError, ValueError):
            stored = None
    if stored != manifest:
        shutil.rmtree(work, ignore_errors=True)
        work.mkdir(parents=True)
        text = json.dumps(manifest, indent=2).encode()
        _write_atomic(work / "manifest.json", lambda fh: fh.write(text))
        resumed = 0
    else:
        resumed = _done_chunks(work, n, d, chunk_rows)
    done = resumed
    if progress is not None:
        progress(done, n)
    while done < n:
        stop = min(n, done + chunk_rows)
        base = done

        def report(k: int, _total: int, base: int = base) -> None:
            if progress is not None:
                progress(base + k, n)

        X = extract_paths(extractor, paths[done:stop], report)
        _write_atomic(work / _chunk_name(done), lambda fh, X=X: np.save(fh, X, allow_pickle=False))
        done = stop
    _assemble(work, out, n, d, chunk_rows)
    shutil.rmtree(work, ignore_errors=True)
    return FolderExtraction(out, n, d, resumed)


def _assemble(work: Path, out: Path, n: int, d: int, chunk_rows: int) -> None:
    """Concatenate the chunks into ``out`` through a memory-mapped temp file (bounded memory)."""
    tmp = out.with_name(f".{out.name}.tmp")
    arr = np.lib.format.open_memmap(tmp, mode="w+", dtype=np.float32, shape=(n, d))
    try:
        for start in range(0, n, chunk_rows):
            arr[start : start + chunk_rows] = np.load(work / _chunk_name(start), allow_pickle=False)
        arr.flush()
    finally:
        del arr
    with open(tmp, "rb+") as fh:
        os.fsync(fh.fileno())
    os.replace(tmp, out)
    fsync_dir(out.parent)

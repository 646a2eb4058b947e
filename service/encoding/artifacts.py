"""Model artifacts: a directory with ``tensors.safetensors`` and ``manifest.json``.

The manifest records the schema version, the model kind and all its parameters, N (the
number of places), how many traversals of them trained the model, d, the
periods, the storage dtype, the footprint and the sha256 of every file. Saving is atomic:
everything is written into a temporary sibling directory, fsynced, and renamed into place,
so a reader sees either no artifact or a complete one; an existing artifact is never
overwritten. Loading verifies the checksums and the schema before any tensor is used.
No pickle is involved anywhere.

A model that can take appended traversals (:mod:`service.encoding.appending`) also stores its
append state, per-class counts and masses, in ``append_state.safetensors``: checksummed like
the tensors, outside the footprint (queries never read it).
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import tempfile
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np
from safetensors import SafetensorError
from safetensors.numpy import load_file, save_file

from service.durable import fsync_dir
from service.encoding.base import PlaceRecognizer
from service.encoding.projection_width import projection_summary
from service.errors import ArtifactError, ConflictError, InvalidInputError

SCHEMA_VERSION = 1
MANIFEST = "manifest.json"
TENSORS = "tensors.safetensors"
APPEND_STATE = "append_state.safetensors"


def _model_classes() -> dict[str, type[PlaceRecognizer]]:
    from service.encoding.baselines import ExactNN, RhythmicEncoder
    from service.encoding.chunked import ChunkedPlaceEncoder
    from service.encoding.encoder import PhaseEncoder
    from service.encoding.pq import PQIndex

    classes: list[type[PlaceRecognizer]] = [
        PhaseEncoder, ChunkedPlaceEncoder, RhythmicEncoder, ExactNN, PQIndex,
    ]  # fmt: skip
    return {c.kind: c for c in classes}


def sha256_file(path: Path) -> str:
    h = hashlib.sha256()
    with path.open("rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def _fsync_file(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _jsonable(value: Any) -> Any:
    if isinstance(value, tuple | list):
        return [_jsonable(v) for v in value]
    if isinstance(value, np.generic):
        return value.item()
    return value


def build_manifest(
    model: PlaceRecognizer, meta: dict[str, Any], extra: dict[str, Any] | None
) -> dict[str, Any]:
    from service import __version__

    params = {k: _jsonable(v) for k, v in model.get_params(deep=False).items()}
    return {
        "schema_version": SCHEMA_VERSION,
        "kind": model.kind,
        "gridplace_version": __version__,
        "created_at": datetime.now(UTC).isoformat(),
        "params": params,
        "n_frames": model.n_frames_,
        "n_places": model.n_frames_,
        "n_traversals": getattr(model, "n_traversals_", 1),
        "n_features": model.n_features_in_,
        "dtype": params.get("dtype"),
        "meta": meta,
        "footprint": model.footprint().to_dict(),
        "projection": projection_summary(model),
        "extra": extra or {},
    }


def check_new_artifact_dir(path: str | os.PathLike[str]) -> Path:
    """Fail now where :func:`save_model` would fail after training: ``path`` exists, or its
    nearest existing ancestor is not a directory this process can create entries in.

    Writability is probed by creating (and removing) a temporary directory there, which
    also catches read-only mounts and holds for root. Returns ``path`` as a :class:`Path`.
    """
    target = Path(path)
    if target.exists() or target.is_symlink():
        raise ConflictError(
            f"{target} already exists; artifacts are immutable, so give a new directory "
            "(or remove the old one)",
            path=str(target),
        )
    ancestor = target.absolute().parent
    while not ancestor.exists() and ancestor != ancestor.parent:
        ancestor = ancestor.parent
    if not ancestor.is_dir():
        raise InvalidInputError(
            f"cannot create {target}: {ancestor} is not a directory", path=str(target)
        )
    try:
        probe = tempfile.mkdtemp(prefix=".gridplace-write-check-", dir=ancestor)
    except OSError as exc:
        raise InvalidInputError(
            f"cannot create {target}: {ancestor} is not writable ({exc.strerror or exc})",
            path=str(target),
        ) from exc
    os.rmdir(probe)
    return target


def save_model(
    model: PlaceRecognizer, path: str | os.PathLike[str], extra: dict[str, Any] | None = None
) -> dict[str, Any]:
    """Write ``model`` to the new directory ``path`` atomically; returns the manifest.

    ``extra`` is free JSON metadata stored in the manifest (e.g. training metrics).
    """
    target = check_new_artifact_dir(path)
    target.parent.mkdir(parents=True, exist_ok=True)
    arrays, meta = model._to_arrays()
    manifest = build_manifest(model, meta, extra)
    tmp = Path(tempfile.mkdtemp(prefix=f".{target.name}.tmp-", dir=target.parent))
    try:
        tensors = tmp / TENSORS
        save_file({k: np.ascontiguousarray(v) for k, v in arrays.items()}, str(tensors))
        _fsync_file(tensors)
        manifest["files"] = {
            TENSORS: {"sha256": sha256_file(tensors), "bytes": tensors.stat().st_size}
        }
        manifest["artifact_bytes"] = tensors.stat().st_size
        state_fn = getattr(model, "_state_arrays", None)
        state = state_fn() if state_fn is not None else {}
        if state:
            path_state = tmp / APPEND_STATE
            save_file({k: np.ascontiguousarray(v) for k, v in state.items()}, str(path_state))
            _fsync_file(path_state)
            manifest["files"][APPEND_STATE] = {
                "sha256": sha256_file(path_state), "bytes": path_state.stat().st_size,
            }  # fmt: skip
        man = tmp / MANIFEST
        man.write_text(json.dumps(manifest, indent=2, sort_keys=True))
        _fsync_file(man)
        fsync_dir(tmp)
        os.rename(tmp, target)  # atomic on one filesystem; fails if target appeared meanwhile
        fsync_dir(target.parent)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return manifest


def read_manifest(path: str | os.PathLike[str]) -> dict[str, Any]:
    """The manifest of the artifact at ``path``, schema-checked (tensors not verified)."""
    man = Path(path) / MANIFEST
    try:
        manifest = json.loads(man.read_text())
    except FileNotFoundError as exc:
        raise ArtifactError(f"no artifact at {path}: {MANIFEST} is missing") from exc
    except (OSError, ValueError) as exc:
        raise ArtifactError(f"unreadable manifest {man}: {exc}") from exc
    if not isinstance(manifest, dict) or manifest.get("schema_version") != SCHEMA_VERSION:
        raise ArtifactError(
            f"artifact {path} has schema version "
            f"{manifest.get('schema_version') if isinstance(manifest, dict) else '?'}; "
            f"this gridplace reads version {SCHEMA_VERSION}"
        )
    return manifest


def load_model(path: str | os.PathLike[str]) -> PlaceRecognizer:
    """Load and verify an artifact written by :func:`save_model`."""
    root = Path(path)
    manifest = read_manifest(root)
    files = manifest.get("files") or {}
    if TENSORS not in files:
        raise ArtifactError(f"artifact {path}: manifest lists no {TENSORS}")
    for name, info in files.items():
        fpath = root / name
        if not fpath.is_file():
            raise ArtifactError(f"artifact {path}: file {name} is missing")
        if sha256_file(fpath) != info.get("sha256"):
            raise ArtifactError(f"artifact {path}: checksum mismatch for {name} (corrupt file)")
    classes = _model_classes()
    cls = classes.get(manifest.get("kind", ""))
    if cls is None:
        raise ArtifactError(f"artifact {path}: unknown model kind {manifest.get('kind')!r}")
    try:
        arrays = load_file(str(root / TENSORS))
        if APPEND_STATE in files:
            arrays.update(load_file(str(root / APPEND_STATE)))
        return cls._from_arrays(manifest["params"], arrays, manifest["meta"])
    except (SafetensorError, KeyError, TypeError, ValueError) as exc:
        raise ArtifactError(f"artifact {path} is inconsistent: {exc}") from exc

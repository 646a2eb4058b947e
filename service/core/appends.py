"""Appending traversals to a map version: a new immutable version, without retraining.

``POST /v1/maps/{name}/versions/{v}/traversals`` (and ``gridplace client append``) sends one or
more traversals of the version's places — descriptors of the version's width, or an image
archive its extractor reads — each optionally with a place index (the place of every row;
without one, row ``i`` is place ``i``), and condition tags ``key=value`` (``season=winter``).
The version's model takes them with :meth:`~service.encoding.encoder.PhaseEncoder.partial_fit`
(:mod:`service.encoding.appending`: time proportional to the new rows) and is published as
the map's next version through the registry, like every version: written atomically into a
new artifact directory, checksummed, recorded in one transaction, so a process killed during
an append leaves no version behind (at most an orphan directory that no row points to,
removed by the registry's orphan cleanup). The version appended to stays as it was.

The new version's ``extra`` records what it was built from: ``appended_to`` (the version),
``traversals`` (every traversal so far: the first version's, then each appended one with its
rows, places, content hash and tags) and ``append`` (seconds, whether the route was extended,
whether condition whitening was learnt). Tagged traversals leave their condition's column
statistics in the model, under the key ``condition_key(tags)`` (``season=winter``), for
queries to name or infer (:mod:`service.core.query_conditions`). Its ``metrics.conditions`` are per-condition
validation figures: for each tag set, how the version appended to localised the new rows
before learning them (within ±5 frames), beside those of earlier appends. An extension (``extend``: places beyond the route)
keeps every existing index; a code whose periods cannot label it answers 409
``retrain_required``.
"""

from __future__ import annotations

import functools
import hashlib
import time
from collections.abc import Sequence
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from service.core.traversal_upload import UploadedFile, check_file_counts, read_places
from service.core.uploads import parse_route, relative_to, store_array, store_descriptors
from service.encoding.conditions import condition_key
from service.errors import (
    DimensionMismatchError,
    InvalidInputError,
    PayloadTooLargeError,
    RetrainRequiredError,
)
from service.imaging import make_extractor, parse_extractor_config
from service.registry.models import VersionInfo
from service.wire.appends import AppendOptions

if TYPE_CHECKING:
    from service.core.localization import LocalizationService

@dataclass(frozen=True)
class NewTraversals:
    """The validated traversals of an append (or a retrain) and the version they go to."""

    base: VersionInfo
    arrays: list[np.ndarray]  # float32 (rows, d), one per traversal
    index: list[np.ndarray]  # each traversal's place index; [] when none was sent
    tags: dict[str, str]


def read_traversals(service: LocalizationService, name: str, version: int,
                    files: Sequence[UploadedFile], places: Sequence[UploadedFile],
                    options: AppendOptions) -> NewTraversals:  # fmt: skip
    """The traversals of an append form, checked against ``version`` of map ``name``: one
    ``file`` per traversal of the version's width (descriptors, or images its extractor reads),
    optionally a place index each, within the upload limit."""
    registry = service.registry
    tags = options.tags()
    base = registry.get_version(name, version)  # 404 before anything is read
    check_file_counts(files, places, "traversal")
    width = int(base.n_features)
    config = base.extractor
    image_config = parse_extractor_config(config)
    extractor_once = functools.cache(lambda: make_extractor(config))

    def check(n_rows: int, n_features: int) -> None:
        if n_features != width:
            raise DimensionMismatchError(
                f"the traversal has descriptors of d={n_features} but map {name!r} version "
                f"{version} takes d={width}", expected=width, got=n_features,
            )  # fmt: skip

    limit = service.settings.max_upload_mb * 1024 * 1024
    used = 0
    arrays: list[np.ndarray] = []
    for upload in files:
        if limit - used <= 0:
            raise PayloadTooLargeError(f"the traversals hold more than the {limit}-byte upload "
                                       "limit (GRIDPLACE_MAX_UPLOAD_MB)", limit_bytes=limit)  # fmt: skip
        X, _ = parse_route(upload.name, upload.fh, limit - used, extractor_once, check,
                           image_config.n_features)  # fmt: skip
        check(*X.shape)
        used += X.nbytes
        arrays.append(X)
    index = [read_places(p, arrays[i].shape[0], limit - used) for i, p in enumerate(places)]
    return NewTraversals(base, arrays, index, tags)


def append_traversals(
    service: LocalizationService, name: str, version: int, files: Sequence[UploadedFile],
    places: Sequence[UploadedFile], options: AppendOptions,
) -> VersionInfo:  # fmt: skip
    """Publish ``version`` of map ``name`` with ``files`` appended as the map's next version."""
    registry = service.registry
    new = read_traversals(service, name, version, files, places, options)
    base, arrays, index, tags = new.base, new.arrays, new.index, new.tags
    model = registry.load_model(name, version)
    n_before = int(model.n_frames_)
    if not hasattr(model, "partial_fit"):
        raise InvalidInputError(
            f"map {name!r} version {version} is a {base.kind}, which takes no appended "
            "traversals; retrain it with them as a job (retrain=true)", kind=base.kind,
        )  # fmt: skip
    conditions = _validation(model, base, arrays, index, tags)
    start = time.perf_counter()
    try:
        model.partial_fit(arrays if len(arrays) > 1 else arrays[0],
                          places=(index if len(index) > 1 else index[0]) if index else None,
                          extend=options.extend, whiten=options.whiten,
                          condition=condition_key(tags))  # fmt: skip
    except RetrainRequiredError as exc:
        raise RetrainRequiredError(
            f"{exc.message}: send the same form with retrain=true (gridplace client append "
            "--retrain), which trains a new version from every traversal of this one and "
            "these as a job", **exc.details,
        ) from exc
    seconds = time.perf_counter() - start
    record = _lineage(base, arrays, index, tags, keep_rows(service.settings.data_dir, arrays, index))
    extra = {"appended_to": version, "traversals": record["traversals"], "append": {
        "seconds": round(seconds, 4), "extended_from": n_before if model.n_frames_ > n_before else None,
        "whitened": getattr(model, "whitening_", None) is not None,
    }}  # fmt: skip
    return registry.publish(
        name, model, params=base.params, extractor=base.extractor,
        metrics={"append_seconds": round(seconds, 4), "conditions": conditions},
        activate=options.activate,
        content_sha256=record["content_sha256"], extra=extra,
    )  # fmt: skip


def _validation(model: Any, base: VersionInfo, arrays: list[np.ndarray], index: list[np.ndarray],
                tags: dict[str, str]) -> dict[str, Any]:  # fmt: skip
    """Per-condition validation figures: how the version appended to localises the new
    traversals before it learns them (rows at its own places, within ±5 frames), keyed by
    the traversals' tags, beside the figures of earlier appends."""
    out = dict(base.metrics.get("conditions") or {})
    rows = np.concatenate(arrays) if len(arrays) > 1 else arrays[0]
    places = np.concatenate(index) if index else np.concatenate([np.arange(a.shape[0]) for a in arrays])
    known = places < int(model.n_frames_)
    if not known.any():
        return out
    pred = model.predict(rows[known])
    key = condition_key(tags) or "untagged"
    out[key] = {"rows": int(known.sum()), "version": base.version,
                "precision_at_5": round(float(np.mean(np.abs(pred - places[known]) <= 5)), 4)}
    return out


def keep_rows(data_dir: Path, arrays: list[np.ndarray], index: list[np.ndarray]) -> list[dict[str, str | None]]:
    """Store each appended traversal's rows (and place index) under ``uploads/``, content
    addressed and atomically as route uploads are, so that a retrain can read them again;
    their paths relative to ``data_dir``."""
    out: list[dict[str, str | None]] = []
    for i, X in enumerate(arrays):
        rows = store_descriptors(data_dir, X, "descriptors").path
        places = store_array(data_dir, index[i], np.int64)[0] if index else None
        out.append({"rows": relative_to(rows, data_dir),
                    "places": None if places is None else relative_to(places, data_dir)})  # fmt: skip
    return out


def _lineage(base: VersionInfo, arrays: list[np.ndarray], index: list[np.ndarray],
             tags: dict[str, str], stored: list[dict[str, str | None]]) -> dict[str, Any]:  # fmt: skip
    """The traversals the new version is built from (where their rows are kept), and a
    content hash covering them all."""
    earlier = list(base.extra.get("traversals") or [{
        "version": base.version, "n_traversals": base.n_traversals,
        "content_sha256": base.content_sha256, "places": [0, base.n_frames - 1],
        "tags": dict(base.extra.get("tags") or {}),
    }])  # fmt: skip
    now = datetime.now(UTC).isoformat()
    h = hashlib.sha256(f"gridplace-append:{base.map}:{base.version}:{base.sha256}".encode())
    for i, X in enumerate(arrays):
        rows = np.ascontiguousarray(X, np.float32)
        sha = hashlib.sha256(rows.tobytes())
        places = index[i] if index else np.arange(rows.shape[0])
        sha.update(np.ascontiguousarray(places, np.int64).tobytes())
        digest = sha.hexdigest()
        h.update(digest.encode())
        earlier.append({"rows": int(rows.shape[0]), "places": [int(places.min()), int(places.max())],
                        "content_sha256": digest, "tags": dict(tags), "stored": stored[i],
                        "appended_to": base.version, "appended_at": now})  # fmt: skip
    return {"traversals": earlier, "content_sha256": h.hexdigest()}

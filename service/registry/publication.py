"""The metadata side of a publish: reserving a version number, checking the descriptor
width against the map's clients, and the ONE transaction that records a written artifact.

:meth:`service.registry.Registry.publish` writes the artifact between
:func:`reserve_version` and :func:`commit_version`; a crash between the two leaves only an
artifact directory without a row, which no reader sees.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from sqlalchemy import Connection, text

from service.encoding.artifacts import MANIFEST, TENSORS
from service.errors import ArtifactError, ConflictError, DimensionChangeError
from service.registry.db import Database, dumps, to_text, utcnow


@dataclass(frozen=True)
class PublishRecord:
    """What a publish records beside the artifact."""

    params: dict[str, Any]
    extractor: dict[str, Any] | None
    metrics: dict[str, Any]
    job_id: str | None
    activate: bool | None
    content_sha256: str | None
    extra: dict[str, Any]
    allow_dimension_change: bool


def reserve_version(db: Database, name: str) -> int:
    """The next version number of ``name``, committed at once and never handed out again."""
    with db.transaction() as conn:
        row = conn.execute(
            text("INSERT INTO version_counters (map, last_reserved) VALUES (:m, 1) "
                 "ON CONFLICT (map) DO UPDATE "
                 "SET last_reserved = version_counters.last_reserved + 1 "
                 "RETURNING last_reserved"),
            {"m": name},
        ).one()  # fmt: skip
    return int(row[0])


def reference_width(conn: Connection, name: str) -> tuple[int, int] | None:
    """``(version, n_features)`` a new version of ``name`` must match: the active version,
    else the newest one; ``None`` for a map without versions."""
    row = conn.execute(
        text("SELECT v.version, v.n_features FROM versions v JOIN maps m ON m.name = v.map "
             "WHERE v.map = :m ORDER BY (v.version = m.active_version) DESC, v.version DESC "
             "LIMIT 1"),
        {"m": name},
    ).first()  # fmt: skip
    return None if row is None else (int(row[0]), int(row[1]))


def width_change(
    reference: tuple[int, int] | None, name: str, n_features: int, allow_change: bool
) -> dict[str, Any] | None:
    """The descriptor-width change a new version makes (``None``: none); a change is refused
    (:class:`DimensionChangeError`) unless ``allow_change``."""
    if reference is None or reference[1] == n_features:
        return None
    version, width = reference
    if not allow_change:
        raise DimensionChangeError(
            f"map {name!r} version {version} takes d={width} descriptors but this route has "
            f"d={n_features}: its clients would break; upload with allow_dimension_change=true "
            "to change the map's descriptor width", map=name, version=version,
            expected=width, got=n_features,
        )  # fmt: skip
    return {"from": width, "to": n_features, "reference_version": version}


def commit_version(
    db: Database, name: str, version: int, path: Path, manifest: dict[str, Any],
    record: PublishRecord,
) -> int | None:
    """The one metadata transaction of a publish; None if the job already published."""
    try:
        sha = manifest["files"][TENSORS]["sha256"]
        artifact_bytes = int(manifest["artifact_bytes"])
        footprint = manifest["footprint"]
        n_features = int(manifest["n_features"])
    except (KeyError, TypeError, ValueError) as exc:
        raise ArtifactError(f"artifact {path} has an incomplete manifest: {exc}") from exc
    job_id = record.job_id
    now = to_text(utcnow())
    with db.transaction() as conn:
        if not (path / MANIFEST).is_file():
            raise ArtifactError(f"artifact {path} disappeared before it was recorded")
        if job_id is not None and conn.execute(
            text("SELECT 1 FROM versions WHERE job_id = :j"), {"j": job_id}
        ).first():
            return None
        if job_id is not None and conn.execute(
            text("SELECT 1 FROM jobs WHERE id = :j AND state = 'failed'"), {"j": job_id}
        ).first():  # serialised with fail_job by the write lock: never both
            raise ConflictError(
                f"training job {job_id} has failed (timed out or cancelled); "
                "its model is not published", job_id=job_id,
            )  # fmt: skip
        # checked again under the lock: a version of another width may have gone live
        change = width_change(reference_width(conn, name), name, n_features,
                              record.allow_dimension_change)  # fmt: skip
        extra = {**record.extra, **({"dimension_change": change} if change else {})}
        conn.execute(
            text("INSERT INTO maps (name, created_at) VALUES (:m, :t) "
                 "ON CONFLICT (name) DO NOTHING"),
            {"m": name, "t": now},
        )  # fmt: skip
        activate = record.activate
        if activate is None:  # the first version (of a new or emptied map) goes live
            activate = not conn.execute(
                text("SELECT 1 FROM versions WHERE map = :m LIMIT 1"), {"m": name}
            ).first()
        conn.execute(
            text("INSERT INTO versions (map, version, n_frames, n_features, kind, params, "
                 "extractor, created_at, sha256, footprint, artifact_bytes, metrics, job_id, "
                 "content_sha256, extra, n_traversals) VALUES (:map, :version, :n_frames, "
                 ":n_features, :kind, :params, :extractor, :created_at, :sha256, :footprint, "
                 ":artifact_bytes, :metrics, :job_id, :content_sha256, :extra, "
                 ":n_traversals)"),
            {"map": name, "version": version, "n_frames": int(manifest["n_frames"]),
             "n_features": n_features, "kind": manifest["kind"],
             "params": dumps(record.params),
             "extractor": None if record.extractor is None else dumps(record.extractor),
             "created_at": now, "sha256": sha, "footprint": dumps(footprint),
             "artifact_bytes": artifact_bytes, "metrics": dumps(record.metrics),
             "job_id": job_id, "content_sha256": record.content_sha256,
             "extra": dumps(extra), "n_traversals": int(manifest.get("n_traversals", 1))},
        )  # fmt: skip
        if activate:
            conn.execute(text("UPDATE maps SET active_version = :v WHERE name = :m"),
                         {"v": version, "m": name})  # fmt: skip
        db.bump_generation(conn)
    return version

"""The versioned model registry: maps, immutable versions, the active version of each map.

Layout under ``data_dir`` (the artifact store, shared by every replica and worker)::

    registry.sqlite3                 maps, versions, jobs, the generation counter (the
                                     embedded default; ``GRIDPLACE_REGISTRY_URL`` puts the
                                     metadata in PostgreSQL instead)
    artifacts/<map>/v<version>/      one artifact per version (manifest.json + tensors)

Publishing reserves a version number (committed at once, never reused), writes the artifact
with :func:`service.encoding.save_model` (temp dir, fsync, rename) and then records the
version in ONE transaction. A crash before that transaction leaves at most an artifact
directory without a row: invisible to every reader, and removed by :meth:`cleanup_orphans`.
A row therefore always points to a complete artifact, and :meth:`load_model` checks it
against the sha256 recorded at publication.
"""

from __future__ import annotations

import os
import re
import shutil
import time
import uuid
from pathlib import Path
from typing import Any

from sqlalchemy import Connection, RowMapping, text

from service.encoding import PlaceRecognizer, load_model, read_manifest, save_model
from service.encoding.artifacts import TENSORS
from service.errors import ArtifactError, ConflictError, NotFoundError
from service.registry.db import Database, JournalMode, loads, sqlite_url, ts
from service.registry.job_table import JobTable
from service.registry.migrations import migrate
from service.registry.models import MapInfo, VersionInfo
from service.registry.names import check_map_name, check_version
from service.registry.publication import (
    PublishRecord,
    commit_version,
    reference_width,
    reserve_version,
    width_change,
)
from service.settings import get_settings

DB_FILE = "registry.sqlite3"
ORPHAN_GRACE_S = 3600.0  # a publish in flight is never this slow between save and commit
_VERSION_DIR = re.compile(r"^v([0-9]+)$")


class Registry(JobTable):
    """Maps, versions and jobs of one artifact store (safe from many processes and hosts)."""

    def __init__(
        self,
        data_dir: Path,
        *,
        url: str | None = None,
        cleanup_grace_s: float | None = ORPHAN_GRACE_S,
        journal_mode: JournalMode | None = None,
    ) -> None:
        """``url``: the registry database, ``settings.registry_url`` when not given, else the
        SQLite file ``data_dir/registry.sqlite3``. ``journal_mode`` (SQLite only) defaults to
        ``settings.registry_journal_mode``. The schema is migrated on start."""
        settings = get_settings()
        self.data_dir = Path(data_dir)
        self.artifacts_dir = self.data_dir / "artifacts"
        self.artifacts_dir.mkdir(parents=True, exist_ok=True)
        url = url or settings.registry_url or sqlite_url(self.data_dir / DB_FILE)
        self.db = Database(
            url, journal_mode=journal_mode or settings.registry_journal_mode,
            pool_size=settings.registry_pool_size,
            connect_timeout_s=settings.registry_connect_timeout_s,
        )  # fmt: skip
        migrate(self.db)
        if cleanup_grace_s is not None:
            self.cleanup_orphans(min_age_s=cleanup_grace_s)

    @property
    def where(self) -> str:
        """The registry database, for messages (no password)."""
        return self.db.where

    def close(self) -> None:
        self.db.close()

    # -- reading --------------------------------------------------------------------------
    def generation(self) -> int:
        """A counter bumped by every publish, activation and deletion (cheap to poll)."""
        with self.db.connect() as conn:
            row = conn.execute(text("SELECT value FROM meta WHERE key = 'generation'")).one()
        return int(row[0])

    def list_maps(self) -> list[MapInfo]:
        with self.db.connect() as conn:
            maps = conn.execute(text("SELECT * FROM maps ORDER BY name")).mappings().all()
            versions = conn.execute(
                text("SELECT map, version FROM versions ORDER BY version")
            ).mappings().all()  # fmt: skip
        by_map: dict[str, list[int]] = {}
        for row in versions:
            by_map.setdefault(row["map"], []).append(int(row["version"]))
        return [self._map_info(row, by_map.get(row["name"], [])) for row in maps]

    def get_map(self, name: str) -> MapInfo:
        check_map_name(name)
        with self.db.connect() as conn:
            row = self._map_row(conn, name)
            versions = [
                int(r[0])
                for r in conn.execute(
                    text("SELECT version FROM versions WHERE map = :m ORDER BY version"),
                    {"m": name},
                )
            ]
        return self._map_info(row, versions)

    def list_versions(self, name: str) -> list[VersionInfo]:
        check_map_name(name)
        with self.db.connect() as conn:
            active = self._map_row(conn, name)["active_version"]
            rows = conn.execute(
                text("SELECT * FROM versions WHERE map = :m ORDER BY version"), {"m": name}
            ).mappings().all()  # fmt: skip
        return [self._version_info(r, active) for r in rows]

    def get_version(self, name: str, version: int) -> VersionInfo:
        check_map_name(name)
        check_version(version)
        with self.db.connect() as conn:
            active = self._map_row(conn, name)["active_version"]
            row = self._version_row(conn, name, version)
        return self._version_info(row, active)

    def active_version(self, name: str) -> VersionInfo | None:
        check_map_name(name)
        with self.db.connect() as conn:
            active = self._map_row(conn, name)["active_version"]
            if active is None:
                return None
            row = self._version_row(conn, name, active)
        return self._version_info(row, active)

    def version_for_job(self, job_id: str) -> VersionInfo | None:
        """The version a training job published, if any."""
        with self.db.connect() as conn:
            row = conn.execute(
                text("SELECT * FROM versions WHERE job_id = :j"), {"j": job_id}
            ).mappings().first()  # fmt: skip
            if row is None:
                return None
            active = self._map_row(conn, row["map"])["active_version"]
        return self._version_info(row, active)

    def reference_width(self, name: str) -> tuple[int, int] | None:
        """``(version, n_features)`` that a new version of ``name`` must match: the active
        version, else the newest one; ``None`` for a map without versions."""
        check_map_name(name)
        with self.db.connect() as conn:
            return reference_width(conn, name)

    def check_width(self, name: str, n_features: int, allow_change: bool) -> dict[str, Any] | None:
        """Refuse (409) a new version of another descriptor width than the map's clients use,
        unless ``allow_change``; returns the change to record (``None``: no change)."""
        with self.db.connect() as conn:
            return width_change(reference_width(conn, name), name, n_features, allow_change)

    def artifact_dir(self, name: str, version: int) -> Path:
        return self.artifacts_dir / check_map_name(name) / f"v{check_version(version)}"

    def load_model(self, name: str, version: int) -> PlaceRecognizer:
        """The model of a version, after checking its files against the recorded sha256."""
        info = self.get_version(name, version)
        path = self.artifact_dir(name, version)
        manifest = read_manifest(path)
        recorded = (manifest.get("files") or {}).get(TENSORS, {}).get("sha256")
        if recorded != info.sha256:
            raise ArtifactError(
                f"map {name!r} version {version}: the artifact's manifest does not match the "
                "registry (artifact replaced or corrupt)", map=name, version=version,
            )  # fmt: skip
        return load_model(path)  # verifies every file's sha256 against the manifest

    # -- writing --------------------------------------------------------------------------
    def publish(
        self,
        name: str,
        model: PlaceRecognizer,
        *,
        params: dict[str, Any],
        extractor: dict[str, Any] | None,
        metrics: dict[str, Any],
        job_id: str | None = None,
        activate: bool | None = None,
        content_sha256: str | None = None,
        extra: dict[str, Any] | None = None,
        allow_dimension_change: bool = False,
    ) -> VersionInfo:
        """Store a fitted model as the next version of ``name``.

        The map is created on its first version. ``activate``: ``None`` activates the version
        only if the map has no other version (the first one), ``True`` activates it, ``False``
        never does. A job publishes at most one version: a retried job gets back the version
        it already published. A model of another descriptor width than the map's active (or
        newest) version is refused (:class:`ConflictError`) unless ``allow_dimension_change``;
        an allowed change is recorded in the version's ``extra["dimension_change"]``.
        ``content_sha256`` is the hash of the route the version was trained on."""
        check_map_name(name)
        model._check_fitted()  # NotFittedError before a version number is spent
        if job_id is not None and (done := self.version_for_job(job_id)) is not None:
            return done
        self.check_width(name, int(model.n_features_in_), allow_dimension_change)
        version = reserve_version(self.db, name)
        path = self.artifact_dir(name, version)
        if path.exists():  # left by a registry database that was lost or replaced
            self._discard(path)
        manifest_extra = {"map": name, "version": version, "job_id": job_id, "metrics": metrics,
                          "extractor": extractor}  # fmt: skip
        manifest = save_model(model, path, extra=manifest_extra)
        record = PublishRecord(params, extractor, metrics, job_id, activate, content_sha256,
                         dict(extra or {}), allow_dimension_change)  # fmt: skip
        try:
            committed = self._commit_version(name, version, path, manifest, record)
        except BaseException:
            self._discard(path)
            raise
        if committed is None:  # another process published this job first
            self._discard(path)
            existing = self.version_for_job(job_id) if job_id is not None else None
            if existing is None:
                raise ConflictError(f"job {job_id} published concurrently; retry")
            return existing
        return self.get_version(name, version)

    def activate(self, name: str, version: int) -> VersionInfo:
        """Make ``version`` the one served for ``name`` (also how a rollback is done)."""
        check_map_name(name)
        check_version(version)
        with self.db.transaction() as conn:
            self._map_row(conn, name)
            self._version_row(conn, name, version)
            conn.execute(text("UPDATE maps SET active_version = :v WHERE name = :m"),
                         {"v": version, "m": name})  # fmt: skip
            self.db.bump_generation(conn)
        return self.get_version(name, version)

    def deactivate(self, name: str) -> MapInfo:
        """Take a map out of service: no version is served until one is activated again."""
        check_map_name(name)
        with self.db.transaction() as conn:
            self._map_row(conn, name)
            conn.execute(text("UPDATE maps SET active_version = NULL WHERE name = :m"),
                         {"m": name})  # fmt: skip
            self.db.bump_generation(conn)
        return self.get_map(name)

    def delete_version(self, name: str, version: int) -> None:
        """Delete an inactive version and its artifact; the active one is refused (409)."""
        check_map_name(name)
        check_version(version)
        with self.db.transaction() as conn:
            active = self._map_row(conn, name)["active_version"]
            self._version_row(conn, name, version)
            if active == version:
                raise ConflictError(
                    f"version {version} is the active version of map {name!r}; "
                    "activate another version first", map=name, version=version,
                )  # fmt: skip
            conn.execute(text("DELETE FROM versions WHERE map = :m AND version = :v"),
                         {"m": name, "v": version})  # fmt: skip
            self.db.bump_generation(conn)
        self._discard(self.artifact_dir(name, version))  # after commit: a crash leaves an orphan

    def cleanup_orphans(self, min_age_s: float = ORPHAN_GRACE_S) -> list[Path]:
        """Remove artifact directories that no version row points to (crashed publishes,
        interrupted deletions, temp dirs), once they are ``min_age_s`` old. Returns them."""
        removed: list[Path] = []
        now = time.time()
        with self.db.connect() as conn:
            known = {(r[0], int(r[1]))
                     for r in conn.execute(text("SELECT map, version FROM versions"))}  # fmt: skip
        for map_dir in sorted(p for p in self.artifacts_dir.iterdir() if p.is_dir()):
            for entry in sorted(map_dir.iterdir()):
                try:
                    age = now - entry.stat().st_mtime
                except FileNotFoundError:
                    continue
                if age < min_age_s:
                    continue
                match = _VERSION_DIR.match(entry.name)
                if match is None:
                    if entry.name.startswith("."):  # save_model temp dirs, our trash
                        shutil.rmtree(entry, ignore_errors=True)
                        removed.append(entry)
                    continue
                if (map_dir.name, int(match.group(1))) in known:
                    continue
                # decide under the write lock: a publish commits only if its directory is
                # still there, so it either wins (row exists) or fails cleanly
                with self.db.transaction() as conn:
                    row = conn.execute(
                        text("SELECT 1 FROM versions WHERE map = :m AND version = :v"),
                        {"m": map_dir.name, "v": int(match.group(1))},
                    ).first()
                    trash = None if row is not None else self._move_to_trash(entry)
                if trash is not None:
                    shutil.rmtree(trash, ignore_errors=True)
                    removed.append(entry)
        return removed

    # -- internals ------------------------------------------------------------------------
    def _commit_version(
        self, name: str, version: int, path: Path, manifest: dict[str, Any], record: PublishRecord
    ) -> int | None:
        """The one metadata transaction of a publish; None if the job already published."""
        return commit_version(self.db, name, version, path, manifest, record)

    def _move_to_trash(self, path: Path) -> Path | None:
        trash = path.with_name(f".trash-{path.name}-{uuid.uuid4().hex[:8]}")
        try:
            os.rename(path, trash)
        except FileNotFoundError:
            return None
        return trash

    def _discard(self, path: Path) -> None:
        trash = self._move_to_trash(path)
        if trash is not None:
            shutil.rmtree(trash, ignore_errors=True)

    @staticmethod
    def _map_row(conn: Connection, name: str) -> RowMapping:
        row = conn.execute(
            text("SELECT * FROM maps WHERE name = :m"), {"m": name}
        ).mappings().first()  # fmt: skip
        if row is None:
            raise NotFoundError(f"no map named {name!r}", map=name)
        return row

    @staticmethod
    def _version_row(conn: Connection, name: str, version: int) -> RowMapping:
        row = conn.execute(
            text("SELECT * FROM versions WHERE map = :m AND version = :v"),
            {"m": name, "v": version},
        ).mappings().first()
        if row is None:
            raise NotFoundError(f"map {name!r} has no version {version}", map=name, version=version)
        return row

    @staticmethod
    def _map_info(row: RowMapping, versions: list[int]) -> MapInfo:
        return MapInfo(
            name=row["name"],
            active_version=row["active_version"],
            versions=versions,
            created_at=ts(row["created_at"]),
        )

    @staticmethod
    def _version_info(row: RowMapping, active: int | None) -> VersionInfo:
        return VersionInfo(
            map=row["map"],
            version=row["version"],
            active=row["version"] == active,
            n_frames=row["n_frames"],
            n_traversals=row["n_traversals"],
            n_features=row["n_features"],
            kind=row["kind"],
            params=loads(row["params"]),
            extractor=loads(row["extractor"]),
            created_at=ts(row["created_at"]),
            sha256=row["sha256"],
            footprint=loads(row["footprint"]),
            artifact_bytes=row["artifact_bytes"],
            metrics=loads(row["metrics"]),
            job_id=row["job_id"],
            content_sha256=row["content_sha256"],
            extra=loads(row["extra"]) or {},
        )

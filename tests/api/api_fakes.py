"""In-memory stand-ins for the registry and training backend (the contract in
service/registry and service/jobs), so the REST layer is tested in-process and alone."""

from __future__ import annotations

import itertools
import threading
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np

from service.encoding import ModelParams, PlaceRecognizer, build_model, load_npy
from service.encoding.traversals import Traversals
from service.errors import ConflictError, DimensionChangeError, NotFoundError, UnavailableError
from service.wire import Job as JobInfo
from service.wire import MapSummary as MapInfo
from service.wire import Version as VersionInfo


class FakeRegistry:
    def __init__(self) -> None:
        self._maps: dict[str, dict[str, Any]] = {}  # mutable MapInfo fields
        self._versions: dict[tuple[str, int], VersionInfo] = {}
        self._models: dict[tuple[str, int], PlaceRecognizer] = {}
        self._gen = 0
        self.loads = 0
        self._lock = threading.Lock()

    def _map(self, name: str) -> dict[str, Any]:
        if name not in self._maps:
            raise NotFoundError(f"unknown map {name!r}")
        return self._maps[name]

    def list_maps(self) -> list[MapInfo]:
        return [self.get_map(name) for name in self._maps]

    def get_map(self, name: str) -> MapInfo:
        m = self._map(name)
        return MapInfo(**{**m, "versions": list(m["versions"])})

    def list_versions(self, name: str) -> list[VersionInfo]:
        return [self.get_version(name, v) for v in self._map(name)["versions"]]

    def get_version(self, name: str, version: int) -> VersionInfo:
        m = self._map(name)
        if (name, version) not in self._versions:
            raise NotFoundError(f"map {name!r} has no version {version}")
        return self._versions[(name, version)].model_copy(
            update={"active": m["active_version"] == version}
        )

    def active_version(self, name: str) -> VersionInfo | None:
        active = self._map(name)["active_version"]
        return None if active is None else self.get_version(name, active)

    def activate(self, name: str, version: int) -> VersionInfo:
        self.get_version(name, version)
        with self._lock:
            self._maps[name]["active_version"] = version
            self._gen += 1
        return self.get_version(name, version)

    def deactivate(self, name: str) -> MapInfo:
        self._map(name)
        with self._lock:
            self._maps[name]["active_version"] = None
            self._gen += 1
        return self.get_map(name)

    def delete_version(self, name: str, version: int) -> None:
        m = self._map(name)
        self.get_version(name, version)
        if m["active_version"] == version:
            raise ConflictError(f"version {version} of {name!r} is active")
        with self._lock:
            m["versions"].remove(version)
            del self._versions[(name, version)]
            self._gen += 1

    def load_model(self, name: str, version: int) -> PlaceRecognizer:
        self.get_version(name, version)
        self.loads += 1
        return self._models[(name, version)]

    def generation(self) -> int:
        return self._gen

    def check_width(self, name: str, n_features: int, allow_change: bool) -> dict[str, Any] | None:
        m = self._maps.get(name)
        if m is None or not m["versions"]:
            return None
        ref = m["active_version"] or max(m["versions"])
        width = self._versions[(name, ref)].n_features
        if width == n_features:
            return None
        if not allow_change:
            raise DimensionChangeError(f"map {name!r} version {ref} takes d={width}, not "
                                       f"d={n_features}", expected=width, got=n_features)  # fmt: skip
        return {"from": width, "to": n_features, "reference_version": ref}

    def publish(self, name: str, model: PlaceRecognizer, *, params: dict[str, Any],
                extractor: dict[str, Any] | None, metrics: dict[str, Any],
                job_id: str | None, activate: bool | None = None) -> VersionInfo:  # fmt: skip
        now = datetime.now(UTC)
        with self._lock:
            m = self._maps.setdefault(name, {"name": name, "active_version": None, "versions": [],
                                             "created_at": now})  # fmt: skip
            version = max(m["versions"], default=0) + 1
            m["versions"].append(version)
            fp = model.footprint().to_dict()
            self._versions[(name, version)] = VersionInfo(
                map=name, version=version, active=False, n_frames=model.n_frames_,
                n_traversals=model.n_traversals_,
                n_features=model.n_features_in_, kind=model.kind, params=params,
                extractor=extractor, created_at=now, sha256="0" * 64, footprint=fp,
                artifact_bytes=int(fp["actual_bytes"]), metrics=metrics, job_id=job_id,
            )  # fmt: skip
            self._models[(name, version)] = model
            if m["active_version"] is None if activate is None else activate:
                m["active_version"] = version
            self._gen += 1
        return self.get_version(name, version)

    def create_empty_map(self, name: str) -> None:
        self._maps[name] = {"name": name, "active_version": None, "versions": [],
                            "created_at": datetime.now(UTC)}  # fmt: skip


class InlineBackend:
    """Trains synchronously inside ``submit`` (small data); can pretend Redis is down."""

    def __init__(self, registry: FakeRegistry) -> None:
        self.registry = registry
        self.jobs: dict[str, JobInfo] = {}
        self.available = True
        self.submitted: list[tuple[str, Path, ModelParams, dict[str, Any] | None]] = []
        self._ids = itertools.count(1)

    def check_available(self) -> None:
        if not self.available:
            raise UnavailableError("the training queue (Redis) is unreachable")

    def submit(self, map_name: str, route: Path, params: ModelParams,
               extractor: dict[str, Any] | None, idempotency_key: str | None, *,
               source: Any = None, force: bool = False) -> JobInfo:  # fmt: skip
        self.check_available()
        for job in self.jobs.values():
            if idempotency_key and (job.map, job.idempotency_key) == (map_name, idempotency_key):
                return job
        now = datetime.now(UTC)
        job = JobInfo(id=f"job-{next(self._ids)}", map=map_name, state="running", stage="training",
                      chunks_done=0, chunks_total=1, created_at=now, started_at=now,
                      finished_at=None, error=None, version=None,
                      idempotency_key=idempotency_key)  # fmt: skip
        self.submitted.append((map_name, route, params, extractor))
        X = load_npy(route)
        if source is not None and source.places is not None:  # several traversals
            places = np.load(route.parent.parent / source.places)
            X = Traversals(X, places, int(places.max()) + 1, source.n_traversals)
        model = build_model(params).fit(X)
        info = self.registry.publish(map_name, model, params=params.model_dump(mode="json"),
                                     extractor=extractor, metrics={}, job_id=job.id)  # fmt: skip
        job = job.model_copy(update={"state": "succeeded", "stage": "done",
                                     "finished_at": datetime.now(UTC), "version": info.version})  # fmt: skip
        self.jobs[job.id] = job
        return job

    def get_job(self, job_id: str) -> JobInfo:
        if job_id not in self.jobs:
            raise NotFoundError(f"no job {job_id!r}")
        return self.jobs[job_id]

    def queue_depth(self) -> int:
        self.check_available()
        return 0

    def close(self) -> None:
        pass

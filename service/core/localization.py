"""THE service layer: every transport (REST, gRPC) calls these methods, and the functions of
:mod:`service.core` that take this service (a route upload, an append, a retrain), and nothing
below them, so validation, errors, metrics and hot-swap semantics are the same everywhere."""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass
from datetime import UTC, datetime
from typing import TYPE_CHECKING, Any

import numpy as np

from service.core.metrics import ServiceMetrics
from service.core.model_store import LoadedModel, ModelStore
from service.core.query_conditions import standardise
from service.core.request_work import check_request
from service.encoding import check_descriptors
from service.errors import (
    ArtifactError,
    ConflictError,
    DimensionMismatchError,
    EmptyInputError,
    InvalidInputError,
    PayloadTooLargeError,
    UnavailableError,
)
from service.imaging import extract_blobs, image_pixels
from service.registry.job_table import MAX_PAGE as MAX_JOB_PAGE
from service.registry.job_cursor import encode_cursor
from service.registry.models import JOB_STATES
from service.registry.names import check_map_name
from service.settings import Settings

if TYPE_CHECKING:
    from service.jobs import TrainingBackend
    from service.registry import JobInfo, MapInfo, Registry, VersionInfo

MAX_BATCH_IMAGES = 4096
SCORE_BLOCK_BYTES = 8 * 1024 * 1024  # float64 frame scores of one block of a batch's rows
MIN_BLOCK_ROWS = 64


def block_rows(entries_per_query: int) -> int:
    """Rows of a batch localized at a time: as many as keep their scores within
    :data:`SCORE_BLOCK_BYTES` (a model with an inverted file holds a few entries per probed list
    where a flat scan holds one per frame: 2.5x faster per query at 1M frames in blocks of
    1,024 rows than of 64), at least :data:`MIN_BLOCK_ROWS`."""
    return max(MIN_BLOCK_ROWS, SCORE_BLOCK_BYTES // (8 * max(1, int(entries_per_query))))


@dataclass(frozen=True)
class LocalizeResult:
    """Answers for a batch of queries against one map version."""

    map: str
    version: int
    index: np.ndarray  # int64 (n,)
    chunk: np.ndarray  # int64 (n,)
    confidence: np.ndarray  # float64 (n,)
    latency_ms: float  # service-layer time: decode + extract + encode
    adapted: bool = False  # standardised by the vehicle's running statistics first
    condition: str | None = None  # the condition the queries were standardised from

    def __len__(self) -> int:
        return int(self.index.shape[0])


def decode_float32(data: bytes, n_features: int | None, what: str = "body") -> np.ndarray:
    """Little-endian float32 bytes → ``(n, d)``; ``d`` from the model when not given."""
    if not data:
        raise EmptyInputError(f"the {what} is empty; send little-endian float32 descriptors")
    if len(data) % 4:
        raise InvalidInputError(
            f"the {what} has {len(data)} bytes, not a whole number of float32 values"
        )
    flat = np.frombuffer(data, dtype="<f4")
    if n_features is None:
        return flat[None, :]
    if flat.size % n_features:
        raise DimensionMismatchError(
            f"the {what} holds {flat.size} float32 values, not a multiple of d={n_features}",
            expected=n_features, got=int(flat.size),
        )  # fmt: skip
    return flat.reshape(-1, n_features)


class LocalizationService:
    def __init__(
        self,
        settings: Settings,
        registry: Registry,
        backend: TrainingBackend,
        store: ModelStore,
        metrics: ServiceMetrics | None = None,
    ) -> None:
        self.settings = settings
        self.registry = registry
        self.backend = backend
        self.store = store
        self.metrics = metrics or ServiceMetrics()
        self._started_at = datetime.now(UTC)

    # -- serving ----------------------------------------------------------------------
    def served(self, name: str) -> LoadedModel:
        """The loaded active version of ``name``: 404 unknown map, 409 none active."""
        loaded = self.store.get(name)
        if loaded is not None:
            return loaded
        info = self.registry.get_map(name)  # NotFoundError for an unknown map
        if info.active_version is None:
            raise ConflictError(
                f"map {name!r} has no active version; activate one first",
                map=name, versions=list(info.versions),
            )  # fmt: skip
        self.store.refresh()
        loaded = self.store.get(name)
        failure = self.store.load_error(name)
        if loaded is None and isinstance(failure, ArtifactError):
            raise ArtifactError(
                f"map {name!r} version {info.active_version} cannot be served: its artifact is "
                "corrupt or unreadable (details in the server log and /readyz); activate another "
                "version or upload the route again", map=name, version=info.active_version,
            )  # fmt: skip
        if loaded is None:
            raise UnavailableError(
                f"map {name!r} version {info.active_version} is not loaded yet; retry shortly",
                map=name, version=info.active_version,
            )  # fmt: skip
        return loaded

    def localize(self, name: str, X: Any, *, input_kind: str = "descriptor",
                 condition: str | None = None) -> LocalizeResult:  # fmt: skip
        """Localize descriptors (``(d,)`` or ``(n, d)``) on the active version of ``name``,
        standardised by ``condition`` when named (:mod:`service.core.query_conditions`)."""
        start = time.perf_counter()
        loaded = self.served(name)  # one reference for the whole request: hot-swap safe
        Q = check_descriptors(X, n_features=loaded.n_features, what="descriptors")
        self.check_work(loaded, Q.shape[0])
        return self._answer(loaded, Q, start, input_kind, condition)

    def localize_bytes(self, name: str, data: bytes, n_features: int | None = None,
                       condition: str | None = None) -> LocalizeResult:  # fmt: skip
        """Localize a raw little-endian float32 body of ``n×d`` values."""
        start = time.perf_counter()
        loaded = self.served(name)
        Q = self.query_bytes(loaded, data, n_features)
        return self._answer(loaded, Q, start, "binary", condition)

    def query_bytes(self, loaded: LoadedModel, data: bytes, n_features: int | None = None,
                    dtype: type = np.float64) -> np.ndarray:  # fmt: skip
        """Validated ``(n, d)`` queries from float32 bytes for ``loaded`` (also used by streams),
        as float64 (or ``dtype=np.float32``: the values as sent, for appearance adaptation)."""
        if n_features is not None and n_features != loaded.n_features:
            raise DimensionMismatchError(
                f"d={n_features} was declared but map {loaded.map!r} version {loaded.version} "
                f"expects d={loaded.n_features}", expected=loaded.n_features, got=n_features,
            )  # fmt: skip
        X = decode_float32(data, loaded.n_features)  # (n, d) of d = n_features: shape holds
        self.check_work(loaded, X.shape[0])
        if np.isfinite(X).all():  # finite as float32 ⇔ finite as float64: nothing else to check
            return X.astype(dtype)
        return check_descriptors(X, n_features=loaded.n_features, what="descriptors")  # raises

    def localize_images(self, name: str, images: Sequence[tuple[str, bytes]],
                        condition: str | None = None) -> LocalizeResult:  # fmt: skip
        """Localize encoded images with the extractor stored with the active version."""
        start = time.perf_counter()
        if not images:
            raise EmptyInputError("no image was sent")
        if len(images) > MAX_BATCH_IMAGES:
            raise InvalidInputError(f"at most {MAX_BATCH_IMAGES} images per request")
        loaded = self.served(name)
        return self._answer(loaded, self.query_images(loaded, images), start, "image", condition)

    def check_work(self, loaded: LoadedModel, rows: int, states: int = 0, pixels: int = 0,
                   images: int = 0, what: str = "the request") -> None:  # fmt: skip
        """413 naming ``GRIDPLACE_MAX_REQUEST_WORK`` beyond the per-request work budget
        (:func:`service.core.request_work.check_request`). A drive's filter runs over every
        route frame; a query alone is scored against the rows its search reads."""
        frames, label = loaded.n_frames, "map frames"
        if not states and frames != loaded.frames_per_query:
            frames, label = loaded.frames_per_query, "rows scored per query"
        check_request(self.settings.max_request_work, frames, rows, states, pixels, images,
                      what, label)  # fmt: skip

    def query_images(self, loaded: LoadedModel, images: Sequence[tuple[str, bytes]],
                     states: int = 0) -> np.ndarray:  # fmt: skip
        """Validated ``(n, d)`` descriptors of encoded images with ``loaded``'s extractor (the
        request's work checked first, with ``states`` filter states per row)."""
        extractor = loaded.extractor()
        if extractor is None:
            raise ConflictError(
                f"map {loaded.map!r} version {loaded.version} was trained on uploaded descriptors "
                "without an image extractor; send descriptors, or train from images",
                map=loaded.map, version=loaded.version,
            )  # fmt: skip
        pixels = self._check_pixel_budget(images)
        self.check_work(loaded, len(images), states, pixels, len(images))
        X = extract_blobs(extractor, images, len(images))  # decoded a small batch at a time
        return check_descriptors(X, n_features=loaded.n_features, what="image descriptors")

    def _check_pixel_budget(self, images: Sequence[tuple[str, bytes]]) -> int:
        """The pixels the images' headers declare; 413 before any decoding when they add up to
        more than one request may make the server decode (``GRIDPLACE_MAX_REQUEST_MEGAPIXELS``)."""
        budget = int(self.settings.max_request_megapixels * 1_000_000)
        total = 0
        for count, (label, data) in enumerate(images, 1):
            total += image_pixels(data, label)
            if total > budget:
                raise PayloadTooLargeError(
                    f"the request's images hold more than {budget} pixels once decoded (the "
                    f"first {count} already {total}); the limit is "
                    f"GRIDPLACE_MAX_REQUEST_MEGAPIXELS={self.settings.max_request_megapixels:g}",
                    limit_pixels=budget,
                )  # fmt: skip
        return total

    def answer(self, loaded: LoadedModel, Q: np.ndarray, start: float, kind: str,
               condition: str | None = None) -> LocalizeResult:  # fmt: skip
        """Localize validated queries on ``loaded`` (standardised by ``condition`` when named)
        and record the metrics (``start``: the request's ``perf_counter`` at arrival)."""
        return self._answer(loaded, Q, start, kind, condition)

    def answer_many(self, loaded: LoadedModel, queries: Sequence[np.ndarray],
                    starts: Sequence[float], kinds: Sequence[str]) -> list[LocalizeResult]:  # fmt: skip
        """Several requests' validated queries on one version, localized in one call (the
        micro-batcher's path); each request keeps its own latency and metrics."""
        sizes = [q.shape[0] for q in queries]
        loc = loaded.model.localize(np.concatenate(queries) if len(queries) > 1 else queries[0])
        index, chunk = loc.index.astype(np.int64), loc.chunk.astype(np.int64)
        conf = loc.confidence.astype(np.float64)
        out: list[LocalizeResult] = []
        done = time.perf_counter()
        offset = 0
        series: dict[str, tuple[Any, Any]] = {}  # a label lookup costs more than an observation
        for size, start, kind in zip(sizes, starts, kinds, strict=True):
            rows = slice(offset, offset + size)
            offset += size
            seconds = done - start
            metric = series.get(kind)
            if metric is None:
                metric = series[kind] = (
                    self.metrics.localize_seconds.labels(map=loaded.map, input=kind),
                    self.metrics.queries.labels(map=loaded.map, input=kind),
                )  # fmt: skip
            metric[0].observe(seconds)
            metric[1].inc(size)
            out.append(LocalizeResult(loaded.map, loaded.version, index[rows], chunk[rows],
                                      conf[rows], seconds * 1000.0))  # fmt: skip
        return out

    def _answer(self, loaded: LoadedModel, Q: np.ndarray, start: float, kind: str,
                condition: str | None = None) -> LocalizeResult:  # fmt: skip
        Q, used = standardise(loaded, Q, condition)
        # a batch is scored a block of rows at a time: the (rows, frames) scores of a large
        # batch would otherwise take far more memory than its body did
        step = block_rows(loaded.entries_per_query)
        blocks = [loaded.model.localize(Q[i : i + step]) for i in range(0, Q.shape[0], step)]
        seconds = time.perf_counter() - start
        self.metrics.localize_seconds.labels(map=loaded.map, input=kind).observe(seconds)
        self.metrics.queries.labels(map=loaded.map, input=kind).inc(Q.shape[0])
        return LocalizeResult(
            loaded.map, loaded.version,
            np.concatenate([b.index for b in blocks]).astype(np.int64),
            np.concatenate([b.chunk for b in blocks]).astype(np.int64),
            np.concatenate([b.confidence for b in blocks]).astype(np.float64), seconds * 1000.0,
            condition=used,
        )  # fmt: skip

    # -- training jobs (a route upload is :func:`service.core.route_submission.submit_route`)
    def get_job(self, job_id: str) -> JobInfo:
        job = self.backend.get_job(job_id)
        self._observe(job)
        return job

    def list_jobs(
        self,
        map_name: str | None = None,
        states: Sequence[str] | None = None,
        limit: int = 50,
        cursor: str | None = None,
    ) -> tuple[list[JobInfo], str | None]:
        """Jobs newest first, one page; returns the page and the cursor of the next one."""
        if map_name is not None:
            check_map_name(map_name)
        if not 1 <= limit <= MAX_JOB_PAGE:
            raise InvalidInputError(f"limit must be 1-{MAX_JOB_PAGE}, got {limit}", limit=limit)
        bad = sorted(set(states or ()) - set(JOB_STATES))
        if bad:
            raise InvalidInputError(
                f"unknown job state {bad[0]!r}: one of {', '.join(JOB_STATES)}", state=bad[0]
            )
        jobs = self.registry.list_jobs(map_name=map_name, states=states or None,
                                       limit=limit + 1, after=cursor)  # fmt: skip
        more = len(jobs) > limit
        jobs = jobs[:limit]
        return jobs, encode_cursor(jobs[-1]) if more else None

    def _observe(self, job: JobInfo) -> None:
        if job.state in ("succeeded", "failed") and job.started_at and job.finished_at:
            finished = job.finished_at
            if finished.tzinfo is None:
                finished = finished.replace(tzinfo=UTC)
            if finished >= self._started_at:  # not jobs of earlier server runs
                secs = (job.finished_at - job.started_at).total_seconds()
                self.metrics.observe_job(job.id, job.state, secs)

    def sync_job_metrics(self) -> None:
        """Record the durations of jobs finished since start (called before a scrape)."""
        list_jobs = getattr(self.registry, "list_jobs", None)
        if list_jobs is None:
            return
        try:
            jobs = list_jobs(states=("succeeded", "failed"), limit=200)
        except UnavailableError:  # the registry is down: a scrape still answers
            return
        for job in jobs:
            self._observe(job)

    def queue_depth(self) -> int | None:
        try:
            return int(self.backend.queue_depth())
        except Exception:  # noqa: BLE001 - a scrape must not fail because Redis is down
            return None

    # -- registry passthrough -----------------------------------------------------------
    def list_maps(self) -> list[MapInfo]:
        return self.registry.list_maps()

    def get_map(self, name: str) -> MapInfo:
        return self.registry.get_map(name)

    def list_versions(self, name: str) -> list[VersionInfo]:
        return self.registry.list_versions(name)

    def get_version(self, name: str, version: int) -> VersionInfo:
        return self.registry.get_version(name, version)

    def activate(self, name: str, version: int) -> VersionInfo:
        """Activate (or roll back to) a version; served by this process when this returns."""
        info = self.registry.activate(name, version)
        self.store.refresh()
        return info

    def deactivate(self, name: str) -> MapInfo:
        """Take a map out of service: localize answers 409 until a version is activated."""
        info = self.registry.deactivate(name)
        self.store.refresh()
        return info

    def delete_version(self, name: str, version: int) -> None:
        self.registry.delete_version(name, version)
        self.store.refresh()

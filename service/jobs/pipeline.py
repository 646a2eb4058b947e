"""The training pipeline as independent steps, shared by every backend.

Each step is a plain module-level function of ``(data_dir, job_id, ...)``: it reads the job's
spec from the registry, does its work, writes its result to the job's workspace (or
publishes the version) and records progress in the registry. The embedded process pool and
the RQ workers run exactly these functions, so the two backends train identical models.

Unchunked route: :func:`train_single`. Chunked route: :func:`prepare`, then
:func:`train_chunk` for every chunk and :func:`train_classifier` (all in parallel), then
:func:`assemble`, which publishes only when every part is there.
"""

from __future__ import annotations

import time
from datetime import UTC, datetime
from collections.abc import Callable
from functools import lru_cache
from pathlib import Path
from typing import Any, cast

import numpy as np

from service.encoding import ModelParams, PlaceRecognizer, build_model, precision_at
from service.encoding.chunk_training import (
    fit_chunk_classifier,
    fit_chunk_encoder,
    fit_front_end,
    plan_chunks,
)
from service.encoding.chunked import ChunkedPlaceEncoder
from service.encoding.conditions import conditions_of_rows
from service.encoding.encoder import PhaseEncoder
from service.encoding.progress import is_per_class
from service.encoding.traversals import Traversals, check_places, chunk_rows, count_places
from service.errors import (
    DimensionMismatchError,
    EmptyInputError,
    GridplaceError,
    NonFiniteInputError,
    UnsafeFileError,
)
from service.jobs.workspace import JobFinished, Prep, Workspace
from service.registry import JobSpec, Registry

EVAL_ROWS = 2000  # training-set precision is measured on at most this many frames
PROGRESS_INTERVAL_S = 0.5  # a part writes its fit progress to the registry at most this often
_BLOCK = 8192


_IN_USE: dict[str, Registry] = {}


def use_registry(registry: Registry) -> None:
    """Make :func:`registry_for` answer ``registry`` for its data directory in this process
    (a server whose registry was configured explicitly runs failure callbacks with it)."""
    _IN_USE[str(registry.data_dir.resolve())] = registry


def registry_for(data_dir: str) -> Registry:
    """One registry handle per data directory and process (workers run many steps): the one
    this process uses, else one from the settings (``GRIDPLACE_REGISTRY_URL``)."""
    return _IN_USE.get(str(Path(data_dir).resolve())) or _registry_from_settings(data_dir)


@lru_cache(maxsize=8)
def _registry_from_settings(data_dir: str) -> Registry:
    return Registry(Path(data_dir), cleanup_grace_s=None)


def describe(exc: BaseException) -> str:
    """A one-line error for the job record."""
    if isinstance(exc, GridplaceError):
        return exc.message
    text = str(exc) or repr(exc)
    return f"{type(exc).__name__}: {text}"


def open_route(path: Path) -> np.ndarray:
    """The route's descriptors, memory-mapped read-only (no pickle, no full copy)."""
    try:
        X = np.load(path, mmap_mode="r", allow_pickle=False)
    except FileNotFoundError as exc:
        raise EmptyInputError(f"the route file {path} is missing") from exc
    except (ValueError, OSError) as exc:
        raise UnsafeFileError(f"the route file {path} is not a plain .npy array: {exc}") from exc
    if X.dtype.kind not in "biuf":
        raise UnsafeFileError(f"the route file {path} holds dtype {X.dtype}, not numbers")
    if X.ndim != 2 or X.shape[0] < 2 or X.shape[1] < 1:
        raise DimensionMismatchError(
            f"the route must be a (frames, features) array with >= 2 frames, got {X.shape}"
        )
    return X


def open_places(data_dir: Path, spec: JobSpec, n_rows: int) -> np.ndarray | None:
    """The place of every route row (``None``: one traversal, row i is place i), checked
    against the route: one integer per row, every place 0…N−1 present."""
    source = spec.source
    if source is None or source.places is None:
        return None
    path = Path(source.places)
    path = path if path.is_absolute() else data_dir / path
    try:
        idx = np.load(path, allow_pickle=False)
    except FileNotFoundError as exc:
        raise EmptyInputError(f"the place-index file {path} is missing") from exc
    except (ValueError, OSError) as exc:
        raise UnsafeFileError(f"the place-index file {path} is not a plain .npy: {exc}") from exc
    idx = check_places(idx, n_rows, f"the place index {path}")
    count_places(idx, n_rows)
    return idx


def _traversals(data_dir: Path, spec: JobSpec, X: np.ndarray) -> Traversals:
    """The job's route as validated traversals (rows converted to float64)."""
    places = open_places(data_dir, spec, X.shape[0])
    n_places = X.shape[0] if places is None else int(places.max()) + 1
    return Traversals(_rows(X, 0, X.shape[0]), places, n_places, _n_traversals(spec))


def _n_traversals(spec: JobSpec) -> int:
    return 1 if spec.source is None else spec.source.n_traversals


def _rows(X: np.ndarray, start: int, stop: int) -> np.ndarray:
    return np.asarray(X[start:stop], dtype=np.float64)


def _check_finite(X: np.ndarray) -> None:
    for s in range(0, X.shape[0], _BLOCK):
        block = np.asarray(X[s : s + _BLOCK])
        if not np.isfinite(block).all():
            row, col = np.argwhere(~np.isfinite(block))[0]
            raise NonFiniteInputError(
                f"the route contains NaN or infinite values (first at row {s + row}, "
                f"column {col})"
            )


def _load(data_dir: Path, job_id: str) -> tuple[Registry, JobSpec, ModelParams]:
    registry = registry_for(str(data_dir))
    spec = registry.get_job_spec(job_id)
    return registry, spec, ModelParams.parse(**spec.params)


def _started(registry: Registry, job_id: str, stage: str, total: int | None = None) -> None:
    if not registry.mark_running(job_id, stage, total):
        raise JobFinished(f"job {job_id} already finished; skipping {stage}")


def _still_open(registry: Registry, job_id: str, what: str) -> None:
    """Re-check the job before writing a result: a part that outlived its job (failed or
    timed out meanwhile, its workspace removed) writes nothing."""
    if registry.get_job(job_id).done:
        raise JobFinished(f"job {job_id} finished while {what} trained; result discarded")


def _write_while_open(registry: Registry, job_id: str, workspace: Workspace, what: str,
                      write: Callable[[], None]) -> None:  # fmt: skip
    """Write a part's result, then check the job again.

    A job is marked failed before its workspace is removed, so a write that raced with the
    removal (checked before it, landed after or during it, and so brought the directory
    back) sees the job done afterwards and removes the workspace itself."""
    _still_open(registry, job_id, what)
    try:
        write()
    finally:
        if registry.get_job(job_id).done:
            workspace.remove()
    _still_open(registry, job_id, what)


class FitReporter:
    """The fit progress of one part of a job (``fit``, ``chunk_3``, ``chunk_classifier``),
    written to the registry: per-class reports at most every :data:`PROGRESS_INTERVAL_S`,
    every step boundary (a digit or chunk starting or ending) and the end always.

    When the job has ended meanwhile (failed elsewhere, timed out), the write raises
    :class:`JobFinished`, which aborts the fit instead of training for nothing.
    """

    def __init__(self, registry: Registry, job_id: str, part: str) -> None:
        self._registry = registry
        self._job_id = job_id
        self._part = part
        self._last = float("-inf")

    def __call__(self, detail: str, done: int, total: int) -> None:
        now = time.monotonic()
        if done < total and is_per_class(detail) and now - self._last < PROGRESS_INTERVAL_S:
            return
        self._last = now
        if self._part != "fit":  # a chunked job's parts run side by side: say which one
            detail = f"{self._part}: {detail}" if detail else self._part
        if not self._registry.record_fit_progress(self._job_id, self._part, done, total, detail):
            raise JobFinished(f"job {self._job_id} already finished; stopping {self._part}")


def _validate(params: ModelParams, n_features: int, sizes: list[int]) -> None:
    """Fail before any training for parameters that cannot fit this route."""
    encoder = cast(PhaseEncoder, build_model(params.model_copy(update={"n_chunks": 1})))
    encoder._validate_params(n_features)
    if params.periods is not None:
        for size in sizes:
            encoder.periods_for(size)  # the code's own rule (mixed radix or residue)


def train_single(data_dir: Path, job_id: str) -> int:
    """Train an unchunked route and publish it; returns the version."""
    registry, spec, params = _load(data_dir, job_id)
    _started(registry, job_id, "fit", 1)
    start = time.perf_counter()
    X = open_route(registry.route_path(spec))
    _check_finite(X)
    route = _traversals(data_dir, spec, X)
    _validate(params, X.shape[1], [route.n_places])
    model = build_model(params).fit(route, progress=FitReporter(registry, job_id, "fit"))
    _record_conditions(model, spec, X)
    fit_s = time.perf_counter() - start
    registry.record_progress(job_id, chunks_done_delta=1, timings={"fit": fit_s}, part="train")
    version, timings = _publish(registry, spec, params, model, X, {"fit": fit_s}, route.places)
    registry.finish_job(job_id, version, timings)
    return version


def prepare(data_dir: Path, job_id: str) -> dict[str, Any]:
    """Check the route against the parameters, fit the route-wide normaliser and plan the
    chunks; returns ``{"n_frames", "n_features", "n_chunks"}``."""
    registry, spec, params = _load(data_dir, job_id)
    _started(registry, job_id, "prepare", params.n_chunks + 1)
    start = time.perf_counter()
    X = open_route(registry.route_path(spec))
    _check_finite(X)
    places = open_places(data_dir, spec, X.shape[0])
    n_places = X.shape[0] if places is None else int(places.max()) + 1
    bounds = plan_chunks(n_places, params.n_chunks)
    _validate(params, X.shape[1], np.diff(bounds).tolist())
    workspace = Workspace(data_dir, job_id)
    prep = Prep(fit_front_end(X, params.model_dump(), bounds), bounds)
    _write_while_open(registry, job_id, workspace, "the preparation",
                      lambda: workspace.save_prep(prep))  # fmt: skip
    registry.record_progress(job_id, timings={"prepare": time.perf_counter() - start},
                             part="prepare")  # fmt: skip
    return {"n_frames": n_places, "n_features": int(X.shape[1]),
            "n_chunks": params.n_chunks}  # fmt: skip


def train_chunk(data_dir: Path, job_id: str, chunk: int) -> float:
    """Train one chunk's encoder on that chunk's rows; returns its seconds."""
    registry, spec, params = _load(data_dir, job_id)
    _started(registry, job_id, "chunks")
    start = time.perf_counter()
    workspace = Workspace(data_dir, job_id)
    prep = workspace.load_prep()
    if not workspace.has_chunk(chunk):  # else an earlier run finished it, unrecorded
        s, e = int(prep.bounds[chunk]), int(prep.bounds[chunk + 1])
        X = open_route(registry.route_path(spec))
        places = open_places(data_dir, spec, X.shape[0])
        if places is None:
            rows, local = _rows(X, s, e), None
        else:  # the rows of the chunk's places, of every traversal
            mine = chunk_rows(places, prep.bounds)[chunk]
            rows, local = np.asarray(X[mine], dtype=np.float64), places[mine] - s
        encoder = fit_chunk_encoder(rows, prep.normalizer, params.model_dump(),
                                    FitReporter(registry, job_id, f"chunk_{chunk}"),
                                    local)  # fmt: skip
        _write_while_open(registry, job_id, workspace, f"chunk {chunk}",
                          lambda: workspace.save_chunk(chunk, encoder))  # fmt: skip
    seconds = time.perf_counter() - start
    registry.record_progress(job_id, chunks_done_delta=1, timings={f"chunk_{chunk}": seconds},
                             part=f"chunk-{chunk}")  # fmt: skip
    return seconds


def train_classifier(data_dir: Path, job_id: str) -> float:
    """Train the chunk classifier on the whole route; returns its seconds."""
    registry, spec, params = _load(data_dir, job_id)
    _started(registry, job_id, "chunks")
    start = time.perf_counter()
    workspace = Workspace(data_dir, job_id)
    prep = workspace.load_prep()
    X = open_route(registry.route_path(spec))
    classifier, tally = fit_chunk_classifier(X, prep.bounds, prep.normalizer, params.model_dump(),
                                             FitReporter(registry, job_id, "chunk_classifier"),
                                             open_places(data_dir, spec, X.shape[0]))  # fmt: skip
    _write_while_open(registry, job_id, workspace, "the chunk classifier",
                      lambda: workspace.save_classifier(classifier, X.shape[1], tally))
    seconds = time.perf_counter() - start
    registry.record_progress(job_id, chunks_done_delta=1, timings={"chunk_classifier": seconds},
                             part="classifier")  # fmt: skip
    return seconds


def assemble(data_dir: Path, job_id: str) -> int:
    """Assemble the chunk results into one model and publish it; returns the version."""
    registry, spec, params = _load(data_dir, job_id)
    _started(registry, job_id, "assemble")
    start = time.perf_counter()
    workspace = Workspace(data_dir, job_id)
    prep = workspace.load_prep()
    X = open_route(registry.route_path(spec))
    encoders = [workspace.load_chunk(c) for c in range(prep.n_chunks)]
    classifier, tally = workspace.load_classifier(X.shape[1])
    model = ChunkedPlaceEncoder.assemble(
        build_model(params).get_params(), prep.normalizer, prep.bounds, classifier, encoders,
        _n_traversals(spec), tally,
    )  # fmt: skip
    _record_conditions(model, spec, X)
    timing = {"assemble": time.perf_counter() - start}
    registry.record_progress(job_id, timings=timing)
    places = open_places(data_dir, spec, X.shape[0])
    version, timings = _publish(registry, spec, params, model, X, timing, places)
    workspace.remove()  # before the job reads succeeded: then nothing of it is left behind
    registry.finish_job(job_id, version, timings)
    return version


def _record_conditions(model: PlaceRecognizer, spec: JobSpec, X: np.ndarray) -> None:
    """The statistics of the route's tagged traversals (a retrain's), for queries to name."""
    if spec.source is not None and spec.source.conditions and hasattr(model, "conditions_"):
        model.conditions_ = conditions_of_rows(X, spec.source.conditions)


def evaluate_on_route(
    model: PlaceRecognizer, X: np.ndarray, places: np.ndarray | None = None
) -> dict[str, Any]:
    """Training-set precision at 0 and 5 frames on (at most EVAL_ROWS) evenly spaced rows
    (of every traversal; ``places``: each row's place, ``None``: row i is place i)."""
    idx = np.unique(np.linspace(0, X.shape[0] - 1, min(X.shape[0], EVAL_ROWS)).astype(np.int64))
    pred = model.predict(np.asarray(X[idx], dtype=np.float64))
    truth = idx if places is None else places[idx]
    return {
        "train_precision_at_0": precision_at(pred, truth, 0),
        "train_precision_at_5": precision_at(pred, truth, 5),
        "eval_frames": int(idx.size),
    }


def _publish(
    registry: Registry,
    spec: JobSpec,
    params: ModelParams,
    model: PlaceRecognizer,
    X: np.ndarray,
    timings: dict[str, float],
    places: np.ndarray | None = None,
) -> tuple[int, dict[str, float]]:
    """Evaluate and publish; returns the version and the timings to record on success."""
    _started(registry, spec.job_id, "publish")
    start = time.perf_counter()
    metrics: dict[str, Any] = evaluate_on_route(model, X, places)
    eval_s = time.perf_counter() - start
    job = registry.get_job(spec.job_id)
    stage_seconds = {**job.timings, **timings, "evaluate": eval_s}
    began = job.started_at or job.created_at
    metrics.update(
        train_seconds=(datetime.now(UTC) - began).total_seconds(),
        stage_seconds=stage_seconds,
        backend=spec.backend,
        n_chunks=params.n_chunks,
        n_traversals=_n_traversals(spec),
    )
    if registry.get_job(spec.job_id).done:  # timed out or failed meanwhile: publish nothing
        raise JobFinished(f"job {spec.job_id} finished before its version was published")
    source = spec.source
    extra = None if source is None or source.lineage is None else {
        "traversals": source.lineage, "retrained_from": source.retrained_from}  # fmt: skip
    info = registry.publish(
        spec.map, model, params=params.model_dump(mode="json"), extractor=spec.extractor,
        metrics=metrics, job_id=spec.job_id, extra=extra,
        content_sha256=None if source is None else source.content_sha256,
        # checked at upload; a job without a recorded upload (library use) is not re-checked
        allow_dimension_change=True if source is None else source.allow_dimension_change,
    )  # fmt: skip
    return info.version, {"evaluate": eval_s, "publish": time.perf_counter() - start}

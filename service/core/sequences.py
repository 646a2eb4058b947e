"""Sequence localisation in the service layer: an ordered batch of frames as one drive.

REST (``POST /v1/localize/sequence``) calls :class:`SequenceLocalizer`; the gRPC stream filters
frame by frame through :mod:`service.core.streams`. Both validate queries with the one
:class:`~service.core.localization.LocalizationService`, record its metrics, and run the filter
of :mod:`service.encoding.sequence` on the model's frame scores. A request is one drive: the
filter starts from a uniform belief, appearance adaptation (:mod:`service.encoding.adaptation`,
``adapt``; the server's ``GRIDPLACE_DRIVE_ADAPTATION`` when not given) from the route's
statistics (or those of the condition the request names or the first frames are closest to,
:mod:`service.core.query_conditions`), and neither is kept after the answer.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from service.core.localization import MAX_BATCH_IMAGES, LocalizationService
from service.core.model_store import LoadedModel
from service.core.query_conditions import new_drive, standardise
from service.core.request_work import Cancellation, cancellable
from service.encoding import check_descriptors
from service.encoding.adaptation import adapt_drive, adapts
from service.encoding.sequence import (
    SequenceConfig,
    check_odometry,
    odometry_in_frames,
    sequence_localize,
)
from service.errors import ConflictError, EmptyInputError, InvalidInputError

MAX_SEQUENCE_FRAMES = 100_000  # query frames of one drive per request


@dataclass(frozen=True)
class SequenceResult:
    """Per-frame answers of one drive on one map version (arrays: one entry per frame)."""

    map: str
    version: int
    index: np.ndarray  # int64 filtered estimate
    chunk: np.ndarray  # int64 chunk holding the filtered estimate
    confidence: np.ndarray  # float64 posterior mass near the estimate
    speed: np.ndarray  # float64 posterior mean speed (frames per query frame)
    raw_index: np.ndarray  # int64 each frame's own answer (what /localize answers)
    raw_confidence: np.ndarray  # float64
    config: SequenceConfig
    latency_ms: float
    adapted: bool = False  # the drive was standardised by its own running statistics
    condition: str | None = None  # the condition it was standardised from

    def __len__(self) -> int:
        return int(self.index.shape[0])


def chunk_of(loaded: LoadedModel, index: np.ndarray | int) -> np.ndarray:
    """The chunk holding each frame index (0 for an unchunked model)."""
    idx = np.asarray(index, dtype=np.int64)
    bounds = getattr(loaded.model, "chunk_bounds_", None)
    if bounds is None:
        return np.zeros_like(idx)
    return np.searchsorted(np.asarray(bounds), idx, side="right").astype(np.int64) - 1


def frame_spacing(loaded: LoadedModel) -> float:
    """The metres between the map's frames recorded at upload (``frame_spacing_m``); a map
    without one cannot take odometry in metres."""
    spacing = loaded.info.params.get("frame_spacing_m")
    if spacing is None:
        raise ConflictError(
            f"map {loaded.map!r} version {loaded.version} records no frame spacing: send "
            "odometry in reference frames, or upload the route with frame_spacing_m"
        )
    return float(spacing)


def odometry_frames(loaded: LoadedModel, n: int, odometry: Any = None,
                    odometry_m: Any = None) -> np.ndarray | None:  # fmt: skip
    """A drive's per-frame displacements in reference frames (NaN: a frame without), from
    ``odometry`` (frames) or ``odometry_m`` (metres over the map's frame spacing), not both."""
    if odometry is not None and odometry_m is not None:
        raise InvalidInputError("send odometry in frames or in metres, not both")
    if odometry_m is not None:
        return odometry_in_frames(odometry_m, n, frame_spacing(loaded))
    return None if odometry is None else check_odometry(odometry, n)


class SequenceLocalizer:
    """Localize ordered frames as one drive, through ``service`` (same validation, metrics and
    hot-swap semantics as ``/localize/batch``: one model version answers the whole drive)."""

    def __init__(self, service: LocalizationService) -> None:
        self.service = service

    def localize(self, name: str, X: Any, config: SequenceConfig, adapt: bool | None = None,
                 odometry: Any = None, odometry_m: Any = None,
                 cancellation: Cancellation | None = None,
                 condition: str | None = None) -> SequenceResult:  # fmt: skip
        start = time.perf_counter()
        loaded = self.service.served(name)
        Q = check_descriptors(X, n_features=loaded.n_features, what="descriptors")
        return self.run(loaded, Q, config, start, "descriptor", adapt, odometry, odometry_m,
                        cancellation, condition)  # fmt: skip

    def localize_bytes(
        self, name: str, data: bytes, n_features: int | None, config: SequenceConfig,
        adapt: bool | None = None, odometry: Any = None, odometry_m: Any = None,
        cancellation: Cancellation | None = None, condition: str | None = None,
    ) -> SequenceResult:  # fmt: skip
        start = time.perf_counter()
        loaded = self.service.served(name)
        Q = self.service.query_bytes(loaded, data, n_features)
        return self.run(loaded, Q, config, start, "binary", adapt, odometry, odometry_m,
                        cancellation, condition)  # fmt: skip

    def localize_images(
        self, name: str, images: Sequence[tuple[str, bytes]], config: SequenceConfig,
        adapt: bool | None = None, odometry: Any = None, odometry_m: Any = None,
        cancellation: Cancellation | None = None, condition: str | None = None,
    ) -> SequenceResult:  # fmt: skip
        start = time.perf_counter()
        if not images:
            raise EmptyInputError("no image was sent")
        if len(images) > MAX_BATCH_IMAGES:
            raise InvalidInputError(f"at most {MAX_BATCH_IMAGES} images per request")
        loaded = self.service.served(name)
        self._check_frames(loaded, len(images))
        Q = self.service.query_images(loaded, images, states=config.n_states)  # work checked
        return self.run(loaded, Q, config, start, "image", adapt, odometry, odometry_m,
                        cancellation, condition)  # fmt: skip

    def adapts(self, loaded: LoadedModel, adapt: bool | None) -> bool:
        """Whether a drive on ``loaded`` is adapted (``adapt=True`` on a map without route
        statistics is refused; the default then goes without)."""
        return adapts(loaded.model, adapt, self.service.settings.drive_adaptation,
                      f"map {loaded.map!r} version {loaded.version}")  # fmt: skip

    def _check_frames(self, loaded: LoadedModel, frames: int) -> None:
        if frames > MAX_SEQUENCE_FRAMES:
            raise InvalidInputError(
                f"a drive holds at most {MAX_SEQUENCE_FRAMES} query frames per request, got "
                f"{frames} (stream longer drives with gRPC LocalizeStream)",
                limit=MAX_SEQUENCE_FRAMES, got=int(frames),
            )  # fmt: skip

    def run(
        self, loaded: LoadedModel, Q: np.ndarray, config: SequenceConfig, start: float, kind: str,
        adapt: bool | None = None, odometry: Any = None, odometry_m: Any = None,
        cancellation: Cancellation | None = None, condition: str | None = None,
    ) -> SequenceResult:  # fmt: skip
        """Filter validated queries ``Q`` (rows in driving order) on ``loaded``, with the
        vehicle's per-frame ``odometry`` (reference frames) or ``odometry_m`` (metres, with the
        map's recorded frame spacing); ``None`` entries: frames without. Refused beyond the
        per-request work budget (frames × N × (S + 8)) before any work; ``cancellation``
        stops the filter between blocks of frames. ``condition``: the drive's
        (:mod:`service.core.query_conditions`)."""
        u = odometry_frames(loaded, Q.shape[0], odometry, odometry_m)
        self._check_frames(loaded, Q.shape[0])
        what = f"a drive of {Q.shape[0]} frames on map {loaded.map!r}"
        self.service.check_work(loaded, Q.shape[0], config.n_states, what=what)
        adapted = self.adapts(loaded, adapt)
        settings = self.service.settings
        if adapted:
            drive = new_drive(loaded, settings.adaptation(), condition, settings.condition_frames)
            Q = adapt_drive(loaded.model, Q, start=drive)
            used: str | None = drive.condition_name
        else:
            Q, used = standardise(loaded, Q, condition)
        raw = self.service.answer(loaded, Q, start, f"sequence_{kind}")
        model, block = cancellable(loaded.model, cancellation, config.n_states, what)
        track = sequence_localize(model, Q, config, block, odometry=u)
        return SequenceResult(
            loaded.map,
            loaded.version,
            track.index,
            chunk_of(loaded, track.index),
            track.confidence,
            track.speed,
            raw.index,
            raw.confidence,
            config,
            (time.perf_counter() - start) * 1000.0,
            adapted,
            used,
        )

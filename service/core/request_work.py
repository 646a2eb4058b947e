"""One work budget for every public request, in one unit, and the stop of abandoned work.

A **unit of work** is one update of one route frame's belief in one state of the sequence
filter (about 4 ns of one core on the development machine). Other work is counted in the same
unit by what it was measured to cost against it:

* scoring one query frame against one route frame: :data:`SCORE_UNITS` (a batch of ``rows``
  descriptors, ``/v1/localize``, ``/batch``, gRPC ``Localize``: ``rows × N × 8``; on a map
  with an inverted file N is the most rows one query's search reads: the list centroids and
  the frames of its ``nprobe`` largest lists);
* a drive (``/v1/localize/sequence``): ``frames × N × (S + 8)``, S the filter's states
  (:attr:`~service.encoding.sequence.SequenceConfig.n_states`: the speed grid, both directions
  with ``reverse``, plus the stopped state), the 8 for the frames' own scores;
* an image: :data:`PIXEL_UNITS` per decoded pixel (summed from the headers before any is
  decoded) and :data:`IMAGE_UNITS` for its descriptor (the default CNN extractor's forward
  pass), on top of its row's work.

A request whose work exceeds ``GRIDPLACE_MAX_REQUEST_WORK`` (millions of units) is refused
with 413 (gRPC ``RESOURCE_EXHAUSTED``) naming the setting, before its filter runs or its images
are decoded. The measured CPU cost per unit, hence the CPU a request may cost, is in
docs/RELIABILITY.md.

A drive runs in a worker thread: :class:`Cancellation` is the flag its transport sets when
the client goes away, checked between blocks of frames (:func:`cancellable`), so abandoned
work stops within one block.
"""

from __future__ import annotations

import threading
from typing import Any

import numpy as np

from service.errors import CancelledError, PayloadTooLargeError

SETTING = "GRIDPLACE_MAX_REQUEST_WORK"
BLOCK_WORK = 20_000_000  # units of a drive between two looks at its cancellation flag
# measured costs in units (docs/RELIABILITY.md, "Work per request"): a frame score 31 ns at
# d = 16 against a filter update's 3.4-4.5 ns; PNG decode, gray conversion and resize 11 ns per
# pixel; the default CNN extractor 146 images/s on one core (docs/RESULTS.md)
SCORE_UNITS = 8
PIXEL_UNITS = 3
IMAGE_UNITS = 2_000_000


def request_units(rows: int, n_frames: int, states: int = 0, pixels: int = 0,
                  images: int = 0) -> int:  # fmt: skip
    """The work of ``rows`` queries against ``n_frames`` route frames, through ``states``
    filter states (0: no filter), with ``images`` images of ``pixels`` pixels in all."""
    return (int(rows) * int(n_frames) * (SCORE_UNITS + int(states))
            + int(pixels) * PIXEL_UNITS + int(images) * IMAGE_UNITS)  # fmt: skip


def check_work(budget_m: float, units: int, what: str, formula: str) -> None:
    """413 naming the budget when ``units`` exceed ``budget_m`` million."""
    budget = int(budget_m * 1_000_000)
    if units > budget:
        raise PayloadTooLargeError(
            f"{what} costs {units:,} units of work ({formula}), more than the per-request "
            f"budget of {budget:,} ({SETTING}={budget_m:g} million); send fewer frames or "
            "images per request (or a smaller speed grid)", work=int(units), budget=budget,
        )  # fmt: skip


def check_request(budget_m: float, n_frames: int, rows: int, states: int = 0, pixels: int = 0,
                  images: int = 0, what: str = "the request",
                  frames_label: str = "map frames") -> None:  # fmt: skip
    """413 when ``rows`` queries scored against ``n_frames`` route frames (and filtered through
    ``states`` states), plus ``images`` images of ``pixels`` pixels decoded and extracted, cost
    more than ``budget_m`` million units. ``frames_label`` names what ``n_frames`` counts in
    the message (the rows an inverted file's search reads, for a query alone)."""
    units = request_units(rows, n_frames, states, pixels, images)
    formula = f"{rows} frames × {n_frames} {frames_label} × ({SCORE_UNITS}" + (
        f" + {states} states)" if states else ")")
    if images:
        formula += f" + {images} images ({pixels} pixels)"
    check_work(budget_m, units, what, formula)


class Cancellation:
    """Set by the transport when the caller went away; read by the worker thread."""

    def __init__(self) -> None:
        self._event = threading.Event()
        self.frames_done = 0

    def cancel(self) -> None:
        self._event.set()

    @property
    def cancelled(self) -> bool:
        return self._event.is_set()

    def check(self, what: str) -> None:
        if self._event.is_set():
            raise CancelledError(f"{what}: the client went away; stopped after "
                                 f"{self.frames_done} frames")  # fmt: skip


class _CancellableScorer:
    """A drive scorer (the tracker's) whose blocks of prepared frames stop when the request is
    cancelled; everything else is the model's own scorer."""

    def __init__(self, scorer: Any, cancellation: Cancellation, what: str) -> None:
        self._scorer, self._cancellation, self._what = scorer, cancellation, what

    def prepare_many(self, Q: np.ndarray) -> Any:
        self._cancellation.check(self._what)
        prepared = self._scorer.prepare_many(Q)
        self._cancellation.frames_done += int(Q.shape[0])
        return prepared

    def __getattr__(self, name: str) -> Any:
        return getattr(self._scorer, name)


class _CancellableModel:
    """A model whose frame scores (or, for the tracker, its drive scorer's prepared frames)
    stop when the request is cancelled: the filter asks for them a block of frames at a time."""

    def __init__(self, model: Any, cancellation: Cancellation, what: str) -> None:
        from service.encoding.drive_scoring import drive_scorer

        self._model, self._cancellation, self._what = model, cancellation, what
        self.n_frames_ = model.n_frames_
        # drive_scorer(self) reads this entry: the tracker scores through the model's scorer
        self.__dict__["_drive_scorer"] = _CancellableScorer(drive_scorer(model), cancellation, what)

    def localize(self, Q: np.ndarray) -> Any:
        """Each frame's own answer (the filter's raw answers), in one call."""
        self._cancellation.check(self._what)
        return self._model.localize(Q)

    def frame_log_scores(self, Q: np.ndarray) -> np.ndarray:
        self._cancellation.check(self._what)
        scores = self._model.frame_log_scores(Q)
        self._cancellation.frames_done += int(Q.shape[0])
        return scores  # type: ignore[no-any-return]


def cancellable(model: Any, cancellation: Cancellation | None, n_states: int,
                what: str) -> tuple[Any, int | None]:  # fmt: skip
    """The model to filter a drive with and its block of frames (``None``: the filter's own),
    so that ``cancellation`` is looked at every :data:`BLOCK_WORK` units at most."""
    if cancellation is None:
        return model, None
    per_frame = max(1, int(model.n_frames_) * max(1, n_states))
    return _CancellableModel(model, cancellation, what), max(1, min(256, BLOCK_WORK // per_frame))

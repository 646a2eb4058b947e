"""Micro-batching: localize requests of many concurrent callers in one model call.

Transports submit work from their own event loops (gRPC unary calls, every frame of every
``LocalizeStream``, REST single-descriptor requests) and await the answer. One worker thread
takes what is queued — the first item, then whatever arrives within ``max_wait_s`` or until
``max_batch`` items — validates each item on its own (a bad one fails alone), groups the
valid ones by served map version, localizes each group with **one** call of the fast path and
resolves every caller's future, with one wake-up per event loop per batch.

What a batch changes is only *when* a query is computed: answers are those of the same
requests sent alone (the decoder certifies index and chunk against float64, so BLAS's
batch-size-dependent rounding cannot change them; confidences agree to float32 rounding),
and a stream's frames, submitted in order, are finished in order — the vehicle's sequence
filter sees them one by one, exactly as unbatched, with its frame scores computed per frame.
Frames that are appearance-adapted are adapted together, all vehicles of the batch in one
vectorised step per frame position (:func:`~service.encoding.adaptation.transform_rows`, the
same answers as one frame at a time) between validation and the model call.
While the worker computes one batch the next one queues, so batches grow with load and
cost no waiting when the server is idle.
"""

from __future__ import annotations

import asyncio
import functools
import logging
import queue
import threading
import time
from collections import defaultdict
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from service.core.localization import LocalizationService, LocalizeResult
from service.encoding import check_descriptors
from service.encoding.adaptation import transform_rows
from service.errors import GridplaceError, UnavailableError

if TYPE_CHECKING:
    from service.core.model_store import LoadedModel
    from service.core.streams import FleetStream, Frame, FrameAnswer
    from service.encoding.adaptation import AppearanceAdapter

log = logging.getLogger("gridplace.batching")

#: validate a request: its served version, its query and (stream frames) the adapter to apply
Prepare = Callable[[], "tuple[LoadedModel, np.ndarray, AppearanceAdapter | None]"]

#: requests larger than this (bytes of descriptors) are computed on their own by the caller's
#: pool: one bulk query must not hold up the small ones the batcher exists for
MAX_BATCHED_BYTES = 64 * 1024


@dataclass(eq=False, slots=True)
class _Item:
    """One request: how to validate it (``prepare``), and how to turn its raw result into
    the caller's answer (``finish``, e.g. a stream's filter step)."""

    prepare: Prepare
    kind: str
    loop: asyncio.AbstractEventLoop
    future: asyncio.Future[Any]
    start: float = field(default_factory=time.perf_counter)
    finish: Callable[[LoadedModel, np.ndarray, LocalizeResult, float, bool], Any] | None = None
    outcome: Any = None
    failed: bool = False
    adapted: bool = False

    def fail(self, exc: BaseException) -> None:
        # without its traceback: the frames it references (and their arrays) are not kept
        # alive until the caller reads the error (unexpected errors are logged with it first)
        self.outcome, self.failed = exc.with_traceback(None), True


@dataclass(frozen=True)
class BatchStats:
    batches: int
    items: int
    largest: int

    @property
    def mean_size(self) -> float:
        return self.items / self.batches if self.batches else 0.0


class MicroBatcher:
    """The worker thread and its queue (``start``/``stop``; submit with the ``async`` calls)."""

    def __init__(self, service: LocalizationService, max_batch: int = 256,
                 max_wait_s: float = 0.0) -> None:  # fmt: skip
        self.service = service
        self.max_batch = max(1, int(max_batch))
        self.max_wait_s = max(0.0, float(max_wait_s))
        self._queue: queue.SimpleQueue[_Item | None] = queue.SimpleQueue()
        self._thread: threading.Thread | None = None
        self._batches = self._items = self._largest = 0

    # -- lifecycle ------------------------------------------------------------------
    @property
    def running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def start(self) -> None:
        if self.running:
            return
        self._thread = threading.Thread(target=self._run, name="gridplace-batcher", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        """Answer what is queued, then end the worker."""
        thread, self._thread = self._thread, None
        if thread is not None:
            self._queue.put(None)
            thread.join(timeout=30)
        late: list[_Item] = []  # submitted while stopping
        while True:
            try:
                item = self._queue.get_nowait()
            except queue.Empty:
                break
            if item is not None:
                item.fail(UnavailableError("the server is shutting down"))
                late.append(item)
        self._resolve(late)

    def stats(self) -> BatchStats:
        return BatchStats(self._batches, self._items, self._largest)

    # -- submission (from any event loop) ---------------------------------------------
    async def localize_bytes(self, name: str, data: bytes, n_features: int | None = None,
                             kind: str = "binary") -> LocalizeResult:  # fmt: skip
        """:meth:`LocalizationService.localize_bytes`, batched."""
        svc = self.service

        def prepare() -> tuple[LoadedModel, np.ndarray, None]:
            loaded = svc.served(name)
            return loaded, svc.query_bytes(loaded, data, n_features), None

        return await self._submit(prepare, kind)  # type: ignore[no-any-return]

    async def localize(self, name: str, X: Any, kind: str = "descriptor") -> LocalizeResult:
        """:meth:`LocalizationService.localize` of descriptors, batched."""
        svc = self.service

        def prepare() -> tuple[LoadedModel, np.ndarray, None]:
            loaded = svc.served(name)
            Q = check_descriptors(X, n_features=loaded.n_features, what="descriptors")
            svc.check_work(loaded, Q.shape[0])
            return loaded, Q, None

        return await self._submit(prepare, kind)  # type: ignore[no-any-return]

    def frame(self, stream: FleetStream, frame: Frame) -> asyncio.Future[FrameAnswer]:
        """A stream frame's answer (a future: submit frames in order, await them in order)."""
        return self._enqueue(lambda: stream.prepare(frame), "stream",
                             functools.partial(stream.finish, frame))  # fmt: skip

    async def _submit(self, prepare: Prepare, kind: str) -> Any:
        return await self._enqueue(prepare, kind, None)

    def _enqueue(self, prepare: Prepare, kind: str,
                 finish: Callable[..., Any] | None) -> asyncio.Future[Any]:  # fmt: skip
        loop = asyncio.get_running_loop()
        item = _Item(prepare, kind, loop, loop.create_future(), finish=finish)
        if not self.running:
            item.future.set_exception(UnavailableError("the localization worker is not running"))
        else:
            self._queue.put(item)
        return item.future

    # -- the worker -----------------------------------------------------------------
    def _run(self) -> None:
        while True:
            first = self._queue.get()
            if first is None:
                return
            batch = [first]
            stop = self._collect(batch)
            try:
                self._process(batch)
            except Exception as exc:  # noqa: BLE001 - never lose the callers: fail the rest
                for item in batch:
                    if item.outcome is None:
                        item.fail(_as_gridplace(exc, "a localize batch"))
            self._resolve(batch)
            if stop:
                return

    def _collect(self, batch: list[_Item]) -> bool:
        """Add queued items (waiting up to ``max_wait_s``); True if ``stop`` was requested."""
        deadline = time.perf_counter() + self.max_wait_s
        while len(batch) < self.max_batch:
            try:
                wait = deadline - time.perf_counter()
                item = self._queue.get(timeout=wait) if wait > 0 else self._queue.get_nowait()
            except queue.Empty:
                return False
            if item is None:
                return True
            batch.append(item)
        return False

    def _process(self, batch: Sequence[_Item]) -> None:
        self.service.metrics.batch_size.observe(len(batch))
        self._batches += 1
        self._items += len(batch)
        self._largest = max(self._largest, len(batch))
        prepared: list[tuple[_Item, LoadedModel, np.ndarray, AppearanceAdapter | None]] = []
        for item in batch:
            try:
                prepared.append((item, *item.prepare()))
            except Exception as exc:  # noqa: BLE001 - the item fails, the batch goes on
                item.fail(_as_gridplace(exc, "validating a localize request"))
        adapted = [k for k, p in enumerate(prepared) if p[3] is not None]
        if adapted:  # every vehicle of the batch, one vectorised step per frame position
            try:
                rows = transform_rows([prepared[k][3] for k in adapted],  # type: ignore[misc]
                                      [prepared[k][2] for k in adapted])  # fmt: skip
            except Exception as exc:  # noqa: BLE001 - only the adapted frames fail
                for k in adapted:
                    prepared[k][0].fail(_as_gridplace(exc, "adapting stream frames"))
                prepared = [p for p in prepared if p[3] is None]
            else:
                for k, row in zip(adapted, rows, strict=True):
                    item, loaded, _, adapter = prepared[k]
                    prepared[k] = (item, loaded, row[None, :], adapter)
        groups: dict[int, list[tuple[_Item, LoadedModel, np.ndarray]]] = defaultdict(list)
        for item, loaded, Q, adapter in prepared:
            item.adapted = adapter is not None
            groups[id(loaded)].append((item, loaded, Q))
        raws: dict[int, tuple[LoadedModel, np.ndarray, LocalizeResult]] = {}
        for members in groups.values():
            loaded = members[0][1]
            try:
                results = self.service.answer_many(loaded, [m[2] for m in members],
                                                   [m[0].start for m in members],
                                                   [m[0].kind for m in members])  # fmt: skip
            except Exception as exc:  # noqa: BLE001 - only this version's group fails
                for item, _, _ in members:
                    item.fail(_as_gridplace(exc, f"localizing on map {loaded.map!r}"))
                continue
            for (item, _, Q), raw in zip(members, results, strict=True):
                raws[id(item)] = (loaded, Q, raw)
        for item in batch:  # submission order: a stream's filter sees its frames in order
            if id(item) not in raws:
                continue
            loaded, Q, raw = raws[id(item)]
            if item.finish is None:
                item.outcome = raw
                continue
            try:
                item.outcome = item.finish(loaded, Q, raw, item.start, item.adapted)
            except Exception as exc:  # noqa: BLE001
                item.fail(_as_gridplace(exc, "finishing a stream frame"))

    def _resolve(self, batch: Sequence[_Item]) -> None:
        by_loop: dict[asyncio.AbstractEventLoop, list[_Item]] = defaultdict(list)
        for item in batch:
            by_loop[item.loop].append(item)
        for loop, items in by_loop.items():
            try:
                loop.call_soon_threadsafe(_set_all, items)
            except RuntimeError:  # the caller's loop is closed: nobody waits any more
                pass


def _as_gridplace(exc: BaseException, what: str) -> GridplaceError:
    """A client's mistake stays itself; anything else is logged and answered as internal."""
    if isinstance(exc, GridplaceError):
        return exc
    log.error("%s failed", what, exc_info=exc)
    return GridplaceError("internal server error")


def _set_all(items: Sequence[_Item]) -> None:
    for item in items:
        if item.future.done():  # the caller gave up (cancelled)
            continue
        if item.failed:
            item.future.set_exception(item.outcome)
        else:
            item.future.set_result(item.outcome)

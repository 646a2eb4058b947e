"""The in-memory active model of every map, hot-swapped when the registry changes.

Readers take one reference to an immutable :class:`LoadedModel` and use it for the whole
request; a refresh builds a new mapping and replaces the reference in one assignment, so an
activation or rollback never fails or blocks a request in flight. A background thread polls
``Registry.generation()`` every ``reload_interval_s``; other processes (a second API replica,
the worker publishing a first version) are picked up the same way.

A version that answers images has its extractor built and run once on a blank frame while
the version loads (:meth:`LoadedModel.preload_extractor`), before it is served and before
readiness: the first image query costs what the others cost, not the import of the network
and its first forward pass (seconds). Without the extractor's packages the version still
loads and serves descriptors; its image queries answer 503 naming the missing extra.
"""

from __future__ import annotations

import io
import logging
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import TYPE_CHECKING, Any

from PIL import Image

from service.encoding import PlaceRecognizer
from service.encoding.ivf_scan import batch_entries_per_query
from service.errors import GridplaceError
from service.imaging import Extractor, extract_blobs, make_extractor

if TYPE_CHECKING:
    from service.registry import Registry, VersionInfo

log = logging.getLogger("gridplace.model_store")


@dataclass(frozen=True)
class LoadedModel:
    map: str
    version: int
    model: PlaceRecognizer
    info: VersionInfo
    extractor_config: dict[str, Any] | None
    loaded_at: float = field(default_factory=time.time)
    _extractor: list[Extractor] = field(default_factory=list, repr=False, compare=False)

    @property
    def n_features(self) -> int:
        return int(self.model.n_features_in_)

    @property
    def n_frames(self) -> int:
        return int(self.model.n_frames_)

    @property
    def frames_per_query(self) -> int:
        """The most rows one query is scored against when it is localized: every route frame,
        or with an inverted file the list centroids and the frames of its probed lists (every
        frame where it probes every list: served by the flat scan)."""
        ivf = getattr(self.model, "ivf_", None)
        return self.n_frames if ivf is None or ivf.probes_everything else ivf.most_scored()

    @property
    def entries_per_query(self) -> int:
        """8-byte score entries one query of a batch holds while it is localized: one per
        route frame, or with an inverted file those of its (query, list) pairs."""
        ivf = getattr(self.model, "ivf_", None)
        if ivf is None:
            return self.n_frames
        return batch_entries_per_query(ivf.nprobe, self.n_features)

    def extractor(self) -> Extractor | None:
        """The version's image extractor (``None`` if it has none); built here only when
        :meth:`preload_extractor` could not (its error is raised again)."""
        if self.extractor_config is None:
            return None
        if not self._extractor:
            self._extractor.append(make_extractor(self.extractor_config))
        return self._extractor[0]

    def preload_extractor(self) -> None:
        """Build the extractor and run it once on a blank frame (a no-op without one). A
        failure (a missing extra: :class:`UnavailableError`) is logged and left to the image
        queries, which raise it again; the version's descriptors are served either way."""
        if self.extractor_config is None or self._extractor:
            return
        try:
            extractor = make_extractor(self.extractor_config)
            config = extractor.config
            size = (int(getattr(config, "width", 64)), int(getattr(config, "height", 32)))
            frame = io.BytesIO()
            Image.new("RGB", size, (127, 127, 127)).save(frame, format="PNG")
            # a query's whole path once: decoding an encoded image, the first forward pass
            extract_blobs(extractor, [("warm-up.png", frame.getvalue())], 1)
        except GridplaceError as exc:
            log.warning("map %s v%s: image queries are unavailable: %s", self.map, self.version,
                        exc.message)  # fmt: skip
            return
        except Exception:  # the descriptors of this version stay servable
            log.exception("map %s v%s: cannot preload the image extractor", self.map, self.version)
            return
        self._extractor.append(extractor)


class ModelStore:
    def __init__(
        self,
        registry: Registry,
        reload_interval_s: float = 1.0,
        on_swap: Callable[[Mapping[str, LoadedModel]], None] | None = None,
    ) -> None:
        self._registry = registry
        self._interval = reload_interval_s
        self._on_swap = on_swap
        self._models: Mapping[str, LoadedModel] = MappingProxyType({})
        self._expected: frozenset[str] = frozenset()
        self._errors: dict[str, str] = {}
        self._failures: dict[str, GridplaceError] = {}
        self._generation: int | None = None
        self._retry_at = 0.0
        self._lock = threading.Lock()  # one refresher at a time; readers never take it
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._synced = threading.Event()

    # -- readers ------------------------------------------------------------------
    def get(self, name: str) -> LoadedModel | None:
        return self._models.get(name)

    def snapshot(self) -> Mapping[str, LoadedModel]:
        return self._models

    def load_error(self, name: str) -> GridplaceError | None:
        """Why the active version of ``name`` failed to load at the last refresh, if it did."""
        return self._failures.get(name)

    def ready(self) -> bool:
        """True once every map with an active version has that version loaded."""
        models = self._models
        return self._synced.is_set() and all(
            m in models for m in self._expected
        ) and not self._errors

    def status(self) -> dict[str, Any]:
        models = self._models
        return {
            "ready": self.ready(),
            "generation": self._generation,
            "loaded": {n: m.version for n, m in sorted(models.items())},
            "pending": sorted(self._expected - set(models)),
            "errors": dict(self._errors),
        }

    # -- refresh --------------------------------------------------------------------
    def refresh(self, force: bool = False) -> bool:
        """Load newly active versions; True if the served set changed."""
        with self._lock:
            gen = self._registry.generation()
            retry_due = bool(self._errors) and time.monotonic() >= self._retry_at
            if not force and gen == self._generation and not retry_due:
                return False
            current = self._models
            new: dict[str, LoadedModel] = {}
            expected: set[str] = set()
            errors: dict[str, str] = {}
            failures: dict[str, GridplaceError] = {}
            for info in self._registry.list_maps():
                if info.active_version is None:
                    continue
                expected.add(info.name)
                have = current.get(info.name)
                if have is not None and have.version == info.active_version:
                    new[info.name] = have
                    continue
                try:
                    new[info.name] = self._load(info.name, info.active_version)
                    log.info("loaded map %s version %s", info.name, info.active_version)
                except GridplaceError as exc:
                    errors[info.name] = f"version {info.active_version}: {exc.message}"
                    failures[info.name] = exc
                    log.error("cannot load map %s v%s: %s", info.name, info.active_version, exc)
                    if have is not None:  # keep serving the previous version
                        new[info.name] = have
            changed = {k: v.version for k, v in new.items()} != {
                k: v.version for k, v in current.items()
            }
            self._models = MappingProxyType(new)  # the atomic swap
            self._expected = frozenset(expected)
            self._errors = errors
            self._failures = failures
            self._generation = gen
            # failed loads are retried, but not more often than every few seconds
            self._retry_at = time.monotonic() + max(5.0 * self._interval, 2.0)
            self._synced.set()
        if changed and self._on_swap is not None:
            self._on_swap(self._models)
        return changed

    def _load(self, name: str, version: int) -> LoadedModel:
        info = self._registry.get_version(name, version)
        model = self._registry.load_model(name, version)
        loaded = LoadedModel(name, version, model, info, info.extractor)
        loaded.preload_extractor()  # before the version is served, so before readiness
        return loaded

    # -- background thread ------------------------------------------------------------
    def start(self) -> None:
        if self._thread is not None:
            return
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name="gridplace-model-store", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=10)
            self._thread = None

    def _run(self) -> None:
        down = False  # the registry is unreachable: serve what is loaded, say so once
        while not self._stop.is_set():
            try:
                self.refresh()
                if down:
                    log.warning("the registry is reachable again; checking for activations")
                    down = False
            except GridplaceError as exc:
                if not down:
                    log.warning("cannot check the registry (%s); serving the loaded versions "
                                "until it answers", exc.message)  # fmt: skip
                    down = True
            except Exception:  # a registry hiccup must not kill the poller
                log.exception("model store refresh failed")
            self._stop.wait(self._interval)

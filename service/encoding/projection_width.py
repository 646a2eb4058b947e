"""The projection width a model is fitted with when it is chosen from the route (``auto_width``,
the product default): at most ``n_components``, at most :data:`ROW_FRACTION` of the training
rows, and no wider than lets the whole model store at most ``N·d`` bytes — exact nearest
neighbour on the route's descriptors as uint8 rows.

Why both bounds:

- **Storage.** A projected model stores the column statistics (``8·d`` B), the projection
  (``m`` rows of ``d`` weights, a scale and a bias each) and its digit classifiers (per class
  ``m`` weights, a scale and a bias; per digit a column mask and a temperature): mostly
  ``m·(d + N)``, so on a short route the fixed ``d × 256`` projection outweighs the data
  (``N = 300``, ``d = 2,048``: PCA-256 stores 621,960 B against the rows' 614,400 B).
  :func:`model_bytes` counts it exactly for ``ρ = 1`` and as an upper bound below.
- **Precision.** Whitened components near the rank of a small sample are noise lifted to unit
  scale. On slices of 100–300 places of Nordland's tuning half A (raw pixels, patch-normalised
  pixels and CNN descriptors, summer → winter within ±5 frames, as sent and adapted) widths of
  0.5 / 0.6 / 0.7 / 0.8 × N scored 54.1 / 55.3 / 55.7 / 55.0 % on average, and the width the
  storage bound alone allows (≈ 0.87 N) scored lower on every descriptor set; hence 0.7.

When not even one component fits — the column statistics (8 B per column) and 9 B per class
alone exceed ``N·d``: ``d ≤ 9``, or fewer than 10 frames at ``d ≥ 512`` (14 at ``d = 32``, 23 at
``d = 16``) — the width is not reduced for storage and the manifest says the model is not
within the bound (:func:`projection_summary`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from typing import Any

ROW_FRACTION = 0.7  # of the training rows: chosen on the tuning half (module docstring)
_ITEMSIZE = {"float64": 8, "float32": 4, "float16": 2, "int8": 1}
RULE = (f"at most n_components, at most {ROW_FRACTION:g} of the training rows, and the model "
        "within N·d bytes (exact NN on uint8 rows)")  # fmt: skip


@dataclass(frozen=True)
class WidthChoice:
    requested: int  # n_components asked for
    width: int  # the width fitted (the projection still caps it at the rank of the rows)
    cap_bytes: int  # N·d
    estimated_bytes: int  # the model's bytes at ``width`` (an upper bound for ρ < 1)
    within_cap: bool

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def _linear_bytes(rows: int, cols: int, dtype: str) -> int:
    """A :class:`~service.encoding.quantization.QuantizedLinear` of ``rows × cols``: weights,
    biases, and for int8 a float32 scale and a float32 bias per row."""
    if dtype == "binary":  # sign bits per row, a float32 width per column
        return rows * math.ceil(cols / 8) + 4 * cols
    size = _ITEMSIZE[dtype]
    per_row = 8 if dtype == "int8" else size
    return rows * (cols * size + per_row)


def model_bytes(width: int, n_features: int, classes: Sequence[int], dtype: str) -> int:
    """Stored bytes of a normalised, projected model of ``width`` components whose digit
    classifiers have ``classes`` classes each, every one reading all ``width`` columns."""
    digits = sum(_linear_bytes(int(c), width, dtype) + math.ceil(width / 8) + 8 for c in classes)
    projection = "int8" if dtype == "binary" else dtype  # the projection of a binary model
    return 8 * n_features + _linear_bytes(width, n_features, projection) + digits


def choose_width(requested: int, n_places: int, n_rows: int, n_features: int,
                 classes: Sequence[int], dtype: str) -> WidthChoice:  # fmt: skip
    """The projection width for a route of ``n_places`` places (``n_rows`` training rows of
    ``n_features`` columns) whose digits have ``classes`` classes each."""
    cap = int(n_places) * int(n_features)
    wanted = max(1, min(int(requested), math.floor(ROW_FRACTION * int(n_rows))))
    fixed = model_bytes(0, n_features, classes, dtype)
    per_eight = model_bytes(8, n_features, classes, dtype) - fixed  # 8 components, masks whole
    width = min(wanted, max(0, (cap - fixed) * 8 // max(1, per_eight)))  # ≥ the largest that fits
    while width > 0 and model_bytes(width, n_features, classes, dtype) > cap:
        width -= 1
    if width < 1:  # nothing fits: keep the width precision asks for, and say so
        width = wanted
    est = model_bytes(width, n_features, classes, dtype)
    return WidthChoice(int(requested), width, cap, est, est <= cap)


def projection_summary(model: Any) -> dict[str, Any] | None:
    """What a fitted model's manifest says about its projection (``None`` without one): the
    width asked for and the width stored, how it was chosen, the bound and whether the stored
    model is within it."""
    front = getattr(model, "normalizer_", None)
    projection = getattr(front, "projection", None)
    if projection is None:
        return None
    stored = int(model.footprint().actual_bytes)
    cap = int(model.n_frames_) * int(model.n_features_in_)
    auto = bool(getattr(model, "auto_width", False))
    return {
        "requested_components": getattr(model, "n_components", None),
        "components": int(projection.n_components),
        "auto_width": auto,
        "rule": RULE if auto else "n_components, capped at the rank of the training rows",
        "cap_bytes": cap,
        "stored_bytes": stored,
        "within_cap": stored <= cap,
    }

"""Storage dtypes for linear weights: float64, float32, float16, int8 with per-row scale, and
binary: one sign bit per weight with a per-column width shared by every class (``w_cj =
±width_j``, no bias: every class template has the same norm, so a bias would be the same
constant for all). Binary suits class templates that a drive's motion disambiguates: 16 bytes
per class at 128 components.

A model quantises its weights once, at the end of ``fit``, and from then on predicts with the
dequantised values; saving and loading move the stored form unchanged, so a loaded model
predicts bit-identically to the one that was saved.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from service.errors import InvalidParameterError

StorageDtype = Literal["float64", "float32", "float16", "int8", "binary"]
DTYPES: tuple[str, ...] = ("float64", "float32", "float16", "int8", "binary")


def check_dtype(dtype: str) -> str:
    if dtype not in DTYPES:
        raise InvalidParameterError(f"unknown dtype {dtype!r}; choose one of {DTYPES}")
    return dtype


@dataclass(frozen=True)
class QuantizedLinear:
    """Weights ``(n_classes, d')`` and biases ``(n_classes,)`` in their stored form."""

    weight: np.ndarray  # stored dtype (int8 for "int8")
    bias: np.ndarray  # float32 for "int8", else the stored dtype
    scale: np.ndarray | None = None  # float32 per row, "int8" only
    width: np.ndarray | None = None  # float32 per column, "binary" only (weight: packed signs)
    _dense: list[np.ndarray] = field(default_factory=list, repr=False, compare=False)

    @classmethod
    def from_dense(cls, W: np.ndarray, b: np.ndarray, dtype: str) -> QuantizedLinear:
        check_dtype(dtype)
        if dtype == "binary":
            width = np.abs(W).mean(axis=0).astype(np.float32)
            signs = np.packbits(np.asarray(W) > 0, axis=1)
            return cls(weight=signs, bias=np.zeros(0, np.float32), width=width)
        if dtype == "int8":
            peak = np.abs(W).max(axis=1)
            scale = np.where(peak > 0, peak / 127.0, 1.0).astype(np.float32)
            q = np.clip(np.rint(W / scale[:, None].astype(np.float64)), -127, 127).astype(np.int8)
            return cls(weight=q, bias=b.astype(np.float32), scale=scale)
        return cls(weight=W.astype(dtype), bias=b.astype(dtype))

    @property
    def dtype(self) -> str:
        if self.width is not None:
            return "binary"
        return "int8" if self.scale is not None else str(self.weight.dtype)

    @property
    def n_classes(self) -> int:
        return int(self.weight.shape[0])

    def dequantized(self) -> tuple[np.ndarray, np.ndarray]:
        """Float64 weights ``(n_classes, d')`` and biases as the stored form defines them."""
        if self.width is not None:
            bits = np.unpackbits(self.weight, axis=1, count=self.width.size)
            W = (2.0 * bits - 1.0) * self.width.astype(np.float64)[None, :]
            return W, np.zeros(self.weight.shape[0])
        W = self.weight.astype(np.float64)
        if self.scale is not None:
            W = W * self.scale.astype(np.float64)[:, None]
        return W, self.bias.astype(np.float64)

    @property
    def dense(self) -> tuple[np.ndarray, np.ndarray]:
        """Float64 weights and biases used for scoring (computed once)."""
        if not self._dense:
            self._dense.extend(self.dequantized())
        return self._dense[0], self._dense[1]

    def scores(self, X: np.ndarray) -> np.ndarray:
        W, b = self.dense
        return X @ W.T + b[None, :]

    @property
    def nbytes(self) -> int:
        extra = sum(a.nbytes for a in (self.scale, self.width) if a is not None)
        return int(self.weight.nbytes + self.bias.nbytes + extra)

    def to_arrays(self, prefix: str) -> dict[str, np.ndarray]:
        out = {f"{prefix}.weight": self.weight, f"{prefix}.bias": self.bias}
        if self.scale is not None:
            out[f"{prefix}.scale"] = self.scale
        if self.width is not None:
            out[f"{prefix}.width"] = self.width
        return out

    @classmethod
    def from_arrays(cls, arrays: dict[str, np.ndarray], prefix: str) -> QuantizedLinear:
        return cls(
            weight=arrays[f"{prefix}.weight"],
            bias=arrays[f"{prefix}.bias"],
            scale=arrays.get(f"{prefix}.scale"),
            width=arrays.get(f"{prefix}.width"),
        )


#: int8 weights whose float32 copy takes at most this many bytes are served from that copy
#: (the fastest products on short routes); larger ones are multiplied from int8 block by block
#: (:func:`int8_products`), so serving holds no float32 copy of a long route's weights.
FLOAT32_COPY_BYTES = 32 << 20
_PRODUCT_ROWS = 8192  # int8 weight rows widened to float32 at a time
_PRODUCT64_ROWS = 2048  # int8 weight rows dequantised to float64 at a time (4 MB at d' = 256)


def int8_products(Z: np.ndarray, weight: np.ndarray, scale: np.ndarray,
                  out: np.ndarray | None = None) -> np.ndarray:  # fmt: skip
    """Float32 ``Z @ (scale·W)ᵀ`` of float32 rows ``Z`` ``(n, d')`` and int8 rows ``W``
    ``(τ, d')`` with per-row ``scale``: ``(Z @ Wᵀ)·scale``, ``W`` widened in row blocks (its
    integers are exact in float32, so the products differ from those of a float32 copy of
    ``scale·W`` by float32 rounding only). ``out``: an ``(n, τ)`` float32 array to fill."""
    n, tau = Z.shape[0], weight.shape[0]
    if out is None:
        out = np.empty((n, tau), dtype=np.float32)
    for s in range(0, tau, _PRODUCT_ROWS):
        e = min(tau, s + _PRODUCT_ROWS)
        np.matmul(Z, weight[s:e].astype(np.float32).T, out=out[:, s:e])
    out *= scale
    return out


def int8_products64(Z: np.ndarray, weight: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """Float64 ``Z @ (scale·W)ᵀ`` of float64 rows ``Z`` and int8 rows ``W`` with per-row
    ``scale``, each row block dequantised in float64 exactly as
    :meth:`QuantizedLinear.dequantized` does (``W·scale``, exact) and multiplied: the
    stored model's float64 products, with :data:`_PRODUCT64_ROWS` rows of float64 weights in
    memory at a time instead of all ``τ``."""
    tau = weight.shape[0]
    out = np.empty((Z.shape[0], tau))
    for s in range(0, tau, _PRODUCT64_ROWS):
        e = min(tau, s + _PRODUCT64_ROWS)
        block = weight[s:e].astype(np.float64)
        block *= scale[s:e, None].astype(np.float64)
        np.matmul(Z, block.T, out=out[:, s:e])
    return out


def int8_max_row_norm(weight: np.ndarray, scale: np.ndarray) -> float:
    """Largest ``‖scale_c·w_c‖`` of int8 rows, in row blocks (no float copy of them all)."""
    best = 0.0
    for s in range(0, weight.shape[0], _PRODUCT_ROWS):
        block = weight[s : s + _PRODUCT_ROWS].astype(np.float32)
        sq = np.einsum("ij,ij->i", block, block, dtype=np.float64)
        best = max(best, float((np.sqrt(sq) * scale[s : s + _PRODUCT_ROWS]).max(initial=0.0)))
    return best


def pack_columns(columns: np.ndarray, n_features: int) -> np.ndarray:
    """Selected column indices as a bit mask of ``ceil(d/8)`` bytes."""
    mask = np.zeros(n_features, dtype=bool)
    mask[columns] = True
    return np.packbits(mask)


def unpack_columns(packed: np.ndarray, n_features: int) -> np.ndarray:
    return np.flatnonzero(np.unpackbits(packed, count=n_features)).astype(np.int64)

"""What a serving plan holds per classifier and per chunk: :class:`DigitBlock` (one linear
classifier's columns, weights as one contiguous block, biases, temperature and the float32
error bound of its scores) and :class:`PhaseBlock` (one phase encoder's digits and how its
frames map to digit labels: mixed radix, a residue code or any label table).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from service.encoding import float64_cache
from service.encoding.exact_decode import log_softmax_last
from service.encoding.phases import index_to_labels, place_values
from service.encoding.quantization import (
    FLOAT32_COPY_BYTES,
    int8_max_row_norm,
    int8_products,
    int8_products64,
)
from service.encoding.residue_decode import is_residue_table

if TYPE_CHECKING:
    from service.encoding.serving_plan import Precision

_U32 = 2.0**-24  # unit roundoff of float32


def _kappa(n: int) -> float:
    """Error factor of a float32 dot product of length ``n`` with rounded inputs."""
    g = (n + 3) * _U32
    return 1.01 * g / (1.0 - g) + 4.0 * n * 2.0**-53


#: float32 weights up to this size stay in a last-level cache between queries, where a
#: matrix-vector product per query beats a matrix product of a few queries
GEMV_CACHED_BYTES = 16 << 20


def gemv_rows(weight_bytes: int) -> int:
    """Queries below which :meth:`DigitBlock.products` multiplies them one at a time.
    OpenBLAS's float32 matrix product of a few rows runs far below its matrix-vector product
    (one BLAS thread, N = 10,000 × 256: 1,216 µs a query at 2 rows, 346 at 8, 225 at 16, 153 at
    24, against 167–186 µs one at a time; in a whole ``robust`` query at 12 rows the two tie);
    where the weights do not stay cached (N = 100,000 × 128: 3.7 ms a matrix-vector product)
    the matrix product wins from 8 rows on."""
    return 10 if weight_bytes <= GEMV_CACHED_BYTES else 4


@dataclass(frozen=True)
class DigitBlock:
    """One linear classifier: selected columns, float32 weights, float64 biases."""

    columns: np.ndarray  # (d',) int64
    weight: np.ndarray  # (τ, d') float32, C-contiguous (the stored array when float32)
    bias: np.ndarray  # (τ,) float64
    linear: Any  # the stored QuantizedLinear (float64 reference products)
    beta: float  # inverse temperature applied to the scores
    error: float  # κ(d')·max‖w_c‖·β: score error per unit of ‖z‖
    kept64: list[tuple[np.ndarray, np.ndarray]] = field(default_factory=list, compare=False,
                                                         repr=False)  # fmt: skip

    rowscale: np.ndarray | None = None  # (τ,) float32 when ``weight`` is the stored int8

    @classmethod
    def of(cls, classifier: Any) -> DigitBlock:
        lin = classifier.linear
        temperature = float(getattr(classifier, "temperature", None) or 1.0)
        beta = 1.0 / temperature
        columns = np.asarray(classifier.columns, dtype=np.int64)
        bias = lin.bias.astype(np.float64) if lin.width is None else np.zeros(lin.n_classes)
        if lin.scale is not None and lin.weight.size * 4 > FLOAT32_COPY_BYTES:
            norm = int8_max_row_norm(lin.weight, lin.scale)
            return cls(columns, lin.weight, bias, lin, beta,
                       _kappa(lin.weight.shape[1]) * norm * 1.001 * beta,
                       rowscale=lin.scale.astype(np.float32))  # fmt: skip
        W = lin.weight
        if lin.width is not None:  # binary: the signs times the column widths
            W32 = _binary_float32(lin.weight, lin.width)
        else:
            if lin.scale is not None:
                W = W.astype(np.float64) * lin.scale.astype(np.float64)[:, None]
            W32 = np.ascontiguousarray(W, dtype=np.float32)
        norm = float(np.sqrt(np.einsum("ij,ij->i", W32, W32, dtype=np.float64)).max(initial=0.0))
        return cls(columns, W32, bias, lin, beta,
                   _kappa(W32.shape[1]) * norm * 1.001 * beta)  # fmt: skip

    def products(self, Zc: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """Float32 ``Zc @ Wᵀ`` of float32 rows already restricted to the columns: one matrix
        product, or for a few rows one matrix-vector product each (:func:`gemv_rows`)."""
        if self.rowscale is not None:
            return int8_products(Zc, self.weight, self.rowscale, out)
        n = Zc.shape[0]
        if 1 < n < gemv_rows(self.weight.nbytes):
            if out is None:
                out = np.empty((n, self.weight.shape[0]), dtype=np.float32)
            for i in range(n):
                np.matmul(self.weight, Zc[i], out=out[i])
            return out
        return np.matmul(Zc, self.weight.T, out=out)

    @property
    def n_classes(self) -> int:
        return int(self.weight.shape[0])

    @property
    def long64(self) -> bool:
        """Whether the float64 weights exceed what :mod:`float64_cache` may keep: their
        products are then made from the int8 rows block by block, never as one float64 copy."""
        return self.weight.size * 8 > float64_cache.CACHE_BYTES

    def raw(self, Z: np.ndarray, precision: Precision, out: np.ndarray | None = None) -> np.ndarray:
        """Scores ``β·(z·w_c + b_c)`` of every class: float32 products of ``Z`` (float32)
        or, for ``float64``, the stored model's own float64 arithmetic."""
        if precision == "float64" and self.rowscale is not None and self.long64:
            prod = int8_products64(Z.take(self.columns, axis=1), self.weight, self.rowscale)
            b = self.bias
        elif precision == "float64":
            W, b = self.dense64()
            prod = Z.take(self.columns, axis=1) @ W.T
        else:  # take() gathers columns ~2x faster than fancy indexing
            prod, b = self.products(Z.take(self.columns, axis=1)), self.bias
        out = np.add(prod, b, out=out)
        if self.beta != 1.0:
            out *= self.beta
        return out

    def dense64(self) -> tuple[np.ndarray, np.ndarray]:
        """Float64 weights exactly as the stored model dequantises them (kept within the
        budget of :mod:`service.encoding.float64_cache`)."""
        return float64_cache.kept(self.kept64, self._make_dense64)

    def _make_dense64(self) -> tuple[np.ndarray, np.ndarray]:
        return self.linear.dequantized()  # type: ignore[no-any-return]

    def log_probs64(self, Z64: np.ndarray) -> np.ndarray:
        return log_softmax_last(self.raw(Z64, "float64"))


@dataclass(frozen=True)
class PhaseBlock:
    """One phase encoder (a chunk): its digits and how frames map to digit labels."""

    digits: tuple[DigitBlock, ...]
    periods: tuple[int, ...]
    n_frames: int
    place: np.ndarray  # (k,) int64 place values of the mixed-radix code
    last: np.ndarray  # (k,) int64 digits of N − 1
    #: (N, k) label table when the labels are neither mixed radix nor residues (a residue
    #: code's labels ``f mod τ_j`` are computed, not stored: 16 bytes a frame at k = 2)
    labels: np.ndarray | None
    error: float  # Σ_j 2·error_j: frame-score error per unit of ‖z‖
    residue: bool = False  # labels ``f mod τ_j``: decoded by branch and bound

    @property
    def tabled(self) -> bool:
        """Whether frames are labelled otherwise than by the mixed radix of the periods."""
        return self.labels is not None or self.residue

    def frame_labels(self, frames: np.ndarray) -> np.ndarray:
        """``(len(frames), k)`` digit labels of the frames ``frames``."""
        frames = np.asarray(frames, dtype=np.int64)
        if self.residue:
            return frames[:, None] % np.asarray(self.periods, dtype=np.int64)
        if self.labels is not None:
            return self.labels[frames]
        return np.asarray(index_to_labels(frames, self.periods), dtype=np.int64)

    @classmethod
    def of(cls, encoder: Any) -> PhaseBlock:
        periods = tuple(int(p) for p in encoder.periods_)
        digits = tuple(DigitBlock.of(dc) for dc in encoder.digits_)
        n = int(encoder.n_frames_)
        if n >= 2 and _residue_code(encoder, periods, digits):  # no (N, k) table, even to check
            last = (n - 1) % np.asarray(periods, dtype=np.int64)
            return cls(digits, periods, n, place_values(periods), last, None,
                       2.0 * sum(d.error for d in digits), True)  # fmt: skip
        labels = _label_table(encoder, periods, n, len(digits))
        last_periods = periods if labels is None else tuple(d.n_classes for d in digits)
        last = index_to_labels([n - 1], periods)[0] if labels is None else labels[-1]
        residue = labels is not None and is_residue_table(labels, last_periods)
        return cls(digits, last_periods, n, place_values(periods), np.asarray(last, np.int64),
                   None if residue else labels, 2.0 * sum(d.error for d in digits),
                   residue)  # fmt: skip

    @property
    def width(self) -> int:
        return max(d.n_classes for d in self.digits)


def _binary_float32(packed: np.ndarray, width: np.ndarray, rows: int = 4096) -> np.ndarray:
    """Float32 ``±width`` of packed sign bits ``(n, ⌈d'/8⌉)``, a block of rows at a time: the
    stored form's float64 weights rounded to float32 (negation is exact), without making
    them (a binary code of 22,000 classes × 128 columns is 22.5 MB in float64)."""
    w = np.asarray(width, dtype=np.float64).astype(np.float32)
    out = np.empty((packed.shape[0], w.size), dtype=np.float32)
    for s in range(0, packed.shape[0], rows):
        bits = np.unpackbits(packed[s : s + rows], axis=1, count=w.size)
        np.copyto(out[s : s + rows], np.where(bits.astype(bool), w, -w))
    return out


def _residue_code(encoder: Any, periods: tuple[int, ...], digits: tuple[DigitBlock, ...]) -> bool:
    """Whether ``encoder`` labels frames ``f mod τ_j`` with one class per residue, on two digits
    or more (where, from two frames on, residues never coincide with the periods' mixed radix)."""
    if getattr(encoder, "code", None) != "residue" or not len(digits) == len(periods) >= 2:
        return False
    return all(d.n_classes == t >= 2 for d, t in zip(digits, periods, strict=True))


def _label_table(encoder: Any, periods: tuple[int, ...], n: int, k: int) -> np.ndarray | None:
    """``None`` for the mixed-radix digits of the periods, else the model's own table."""
    table_fn = getattr(encoder, "frame_labels_", None)
    if table_fn is None:
        return None
    table = np.asarray(table_fn() if callable(table_fn) else table_fn, dtype=np.int64)
    if k == len(periods) and math.prod(periods) >= n and np.array_equal(
        table, index_to_labels(np.arange(n), periods)
    ):
        return None
    return table

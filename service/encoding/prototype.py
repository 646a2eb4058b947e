"""The ``prototype`` trainer: each class's weight row is the mean direction of its rows.

``W[c] = m_c / ‖m_c‖`` with ``m_c`` the mean of the training rows labelled ``c``, and bias 0,
so on L2-normalised rows (the projection front-end) a class scores the cosine between the
query and its class mean. Closed form, one pass over the rows; no regularisation, so ``C``
is ignored. The scores are cosines in ``[−1, 1]``: the classifier's ``temperature`` turns
them into log-probabilities (:mod:`service.encoding.calibration`).

With one class per frame and one traversal (the ``robust`` preset) a class's mean is its one
row, so :func:`stream_frame_prototypes` fits a long route in row blocks.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from service.encoding.patterns import add_group_sums
from service.encoding.progress import StepFn
from service.encoding.quantization import QuantizedLinear

_MIN_NORM = 1e-12  # a class whose rows cancel out scores 0 rather than NaN

#: Temperature of prototype classifiers when none is given: about what
#: :func:`service.encoding.calibration.calibrate` fits for a ``k = 2`` residue code (the
#: ``residue`` preset; the ``robust`` preset, ``k = 1``, names its own, 0.028) on the
#: tuning half of Nordland (summer reference, winter queries: 0.070 on
#: patch-normalised frames, 0.066 on CNN descriptors). Scores are cosines, so it is a
#: property of the score scale and of ``k`` rather than of one route; calibrate a model on
#: held-out queries of its own route where there are some.
DEFAULT_TEMPERATURE = 0.07


def fit_prototypes(
    X: np.ndarray, y: np.ndarray, n: int, C: float = 1.0, seed: int | None = None,
    threads: int = 1,
) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """``(W, b)`` for labels ``y`` in ``[0, n)`` (every class present)."""
    del C, seed, threads
    sums = np.zeros((n, X.shape[1]), dtype=np.float64)
    add_group_sums(X, y, sums)
    return unit_rows(sums)[0], np.zeros(n)


def unit_rows(sums: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Class sums ``(τ, d)`` as unit rows (a prototype: the direction of its class mean) and
    their norms (a class whose rows cancel out gets a zero row)."""
    norms = np.sqrt(np.einsum("ij,ij->i", sums, sums))
    return sums / np.maximum(norms, _MIN_NORM)[:, None], norms


_STREAM_ROWS = 16_384  # route rows projected and quantised at a time


def stream_frame_prototypes(
    X: np.ndarray, transform: Callable[[np.ndarray], np.ndarray], dtype: str,
    progress: StepFn | None = None,
) -> tuple[QuantizedLinear, np.ndarray]:  # fmt: skip
    """:func:`fit_prototypes` of one traversal with one class per row (class ``i`` is row
    ``i``), in row blocks: each block of ``X`` (float32 or float64, a memory map of a long
    route) goes through ``transform`` (the front-end) and is stored at ``dtype`` at once, so
    nothing holds ``N × d`` or ``N × d'`` float64. Returns the stored weights (biases 0) and
    the columns' between-class sums of squares of the transformed rows (:func:`bcss` with
    every row its own class: ``Σ_i (z_i − z̄)²`` per column)."""
    n = X.shape[0]
    weights, scales, biases = [], [], []
    total: np.ndarray | None = None
    squares: np.ndarray | None = None
    for s in range(0, n, _STREAM_ROWS):
        Z = np.asarray(transform(X[s : s + _STREAM_ROWS]), dtype=np.float64)
        norms = np.sqrt(np.einsum("ij,ij->i", Z, Z))[:, None]
        W = Z / np.maximum(norms, _MIN_NORM)
        lin = QuantizedLinear.from_dense(W, np.zeros(Z.shape[0]), dtype)
        weights.append(lin.weight)
        biases.append(lin.bias)
        if lin.scale is not None:
            scales.append(lin.scale)
        total = Z.sum(axis=0) if total is None else total + Z.sum(axis=0)
        sq = np.einsum("ij,ij->j", Z, Z)
        squares = sq if squares is None else squares + sq
        if progress is not None:
            progress(min(n, s + _STREAM_ROWS), n)
    assert total is not None and squares is not None
    linear = QuantizedLinear(np.concatenate(weights), np.concatenate(biases),
                             np.concatenate(scales) if scales else None)  # fmt: skip
    return linear, np.maximum(squares - total * total / n, 0.0)

"""Fits of the ``prototype`` trainer that stream one traversal of the route in row blocks.

A prototype classifier needs only per-class sums of the rows that went through the
front-end (its weights are the normalised class means, its pattern the columns'
between-class sums of squares, its append state the class counts and masses), and those add
up block by block. So a long route (a memory map) is never held as one ``N × d`` or
``N × d'`` float64 array:

- :func:`fit_frame_prototypes`: one class per frame (``k = 1``, the ``robust`` preset): a
  class mean is the frame's own row, stored as soon as its block is projected;
- :func:`fit_class_prototypes`: several digits with fewer classes than frames (the residue
  code of the ``drive`` preset): each digit's ``(τ_j, d')`` class sums are accumulated over
  the blocks; the model is that of the in-memory fit up to float rounding (the sums are
  added per block instead of in one pass).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from service.encoding import appending
from service.encoding.digit_classifier import DigitClassifier
from service.encoding.front_end import FrontEnd
from service.encoding.patterns import add_group_sums, bcss_from_sums, select_columns
from service.encoding.progress import ProgressFn, Steps
from service.encoding.prototype import stream_frame_prototypes, unit_rows
from service.encoding.quantization import QuantizedLinear

STREAM_ROWS = 16_384  # route rows projected and accumulated at a time


def fit_frame_prototypes(model: Any, X: np.ndarray, front: FrontEnd,
                         progress: ProgressFn | None) -> None:  # fmt: skip
    """One prototype per row, the route streamed through the front-end
    (:func:`service.encoding.prototype.stream_frame_prototypes`)."""
    n = X.shape[0]
    model.periods_ = model.periods_for(n)
    steps = Steps(progress, ["digit 1/1"], model.periods_)
    linear, scores = stream_frame_prototypes(X, front.transform, model.dtype, steps.step(0))
    steps.done(0)
    pattern = select_columns(scores, float(model.rho), model.gamma)
    model.digits_ = [DigitClassifier(pattern.columns, linear, pattern, model._temperature())]
    model.tallies_ = [appending.streamed_tally(X, front)]
    model.whitening_ = None
    model._set_fitted(n, int(linear.weight.shape[1]), 1)


def class_sums_streamed(
    X: np.ndarray, front: FrontEnd, periods: tuple[int, ...], progress: Any = None,
) -> list[np.ndarray]:  # fmt: skip
    """``(τ_j, d')`` float64 sums of the transformed rows of every residue class
    ``i mod τ_j``, accumulated over blocks of :data:`STREAM_ROWS` rows of ``X``."""
    n = X.shape[0]
    sums: list[np.ndarray] | None = None
    for s in range(0, n, STREAM_ROWS):
        Z = np.asarray(front.transform(X[s : s + STREAM_ROWS]), dtype=np.float64)
        rows = np.arange(s, s + Z.shape[0], dtype=np.int64)
        if sums is None:
            sums = [np.zeros((tau, Z.shape[1])) for tau in periods]
        for j, tau in enumerate(periods):
            add_group_sums(Z, rows % tau, sums[j])
        if progress is not None:
            progress(min(n, s + STREAM_ROWS), n)
    assert sums is not None
    return sums


def fit_class_prototypes(model: Any, X: np.ndarray, front: FrontEnd,
                         progress: ProgressFn | None) -> None:  # fmt: skip
    """The residue digits of ``model`` (``prototype`` trainer, one traversal, every period
    at most ``N``) from class sums streamed over the route: pattern, weights and tallies as
    :meth:`PhaseEncoder._fit_normalised` computes them from the whole projected route."""
    n = X.shape[0]
    model.periods_ = model.periods_for(n)
    k = len(model.periods_)
    steps = Steps(progress, [f"digit {j + 1}/{k}" for j in range(k)], model.periods_)
    sums = class_sums_streamed(X, front, model.periods_, steps.step(0))  # the one pass
    model.digits_, model.tallies_ = [], []
    for j, (tau, S) in enumerate(zip(model.periods_, sums, strict=True)):
        counts = np.bincount(np.arange(n, dtype=np.int64) % tau, minlength=tau)
        pattern = select_columns(bcss_from_sums(S, counts.astype(np.float64), n),
                                 float(model.rho), model.gamma)  # fmt: skip
        W, mass = unit_rows(S[:, pattern.columns])
        linear = QuantizedLinear.from_dense(W, np.zeros(tau), model.dtype)
        model.digits_.append(DigitClassifier(pattern.columns, linear, pattern,
                                             model._temperature()))  # fmt: skip
        model.tallies_.append(appending.ClassTally(counts.astype(np.uint32), mass))
        if j:
            steps.step(j)
        steps.done(j)
    model.whitening_ = None
    model._set_fitted(n, int(sums[0].shape[1]), 1)

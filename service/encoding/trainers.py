"""Pluggable one-vs-rest linear trainers behind one interface.

Every trainer takes the selected columns of the (normalised) training rows and the digit
labels and returns the same arrays: ``W`` of shape ``(n_classes, d')`` and ``b`` of shape
``(n_classes,)``; the score of class ``c`` is ``x·W[c] + b[c]``. A class absent from the
training labels gets ``W[c] = 0`` and ``b[c] = −inf`` so it can never be decoded.

All trainers minimise ``½||w||² + C·Σ loss`` per class (the intercept is regularised only
where LIBLINEAR does so, in ``logreg`` and ``svm``):

- ``logreg``: L2 logistic regression through LIBLINEAR (the paper's public code: ``-s 0``,
  ``C = 4``, bias term).
- ``svm``: L2 squared-hinge linear SVM (LinearSVC), as the paper's text says.
- ``ridge``: closed-form least squares on one-hot targets, in whichever of the primal
  ``d'×d'`` or dual ``N×N`` systems is smaller.
- ``torch``: all classes at once with L-BFGS on the logistic loss; CUDA when available.
- ``prototype``: each class's normalised mean row, bias 0 (:mod:`service.encoding.prototype`;
  no loss, ``C`` unused).
"""

from __future__ import annotations

import itertools
import os
import warnings
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from typing import Any, Literal

import numpy as np

from service.encoding.progress import StepFn
from service.encoding.prototype import fit_prototypes
from service.errors import InvalidParameterError

TrainerName = Literal["logreg", "svm", "ridge", "torch", "prototype"]
TRAINERS: tuple[str, ...] = ("logreg", "svm", "ridge", "torch", "prototype")

LinearModel = tuple[np.ndarray, np.ndarray]


def train_linear(
    X: np.ndarray,
    y: np.ndarray,
    n_classes: int,
    trainer: str = "logreg",
    C: float = 4.0,
    random_state: int | None = 0,
    n_jobs: int = 1,
    progress: StepFn | None = None,
) -> LinearModel:
    """Fit a one-vs-rest linear classifier; returns ``(W, b)`` in float64.

    ``n_jobs`` threads solve the binary problems of ``logreg`` and ``svm`` concurrently
    (LIBLINEAR releases the GIL); ``-1`` uses every core. ``progress(done, total)`` is
    called as classes finish (per binary problem, or all at once for ``ridge``/``torch``).
    """
    if trainer not in _TRAINERS:
        raise InvalidParameterError(f"unknown trainer {trainer!r}; choose one of {TRAINERS}")
    if not C > 0:
        raise InvalidParameterError(f"C must be > 0, got {C}")
    X = np.ascontiguousarray(X, dtype=np.float64)
    y = np.asarray(y, dtype=np.int64)
    present = np.flatnonzero(np.bincount(y, minlength=n_classes) > 0)
    W = np.zeros((n_classes, X.shape[1]), dtype=np.float64)
    b = np.full(n_classes, -np.inf, dtype=np.float64)
    if present.size == 1:  # a digit that never changes on this route carries no information
        b[present] = 0.0
        if progress is not None:
            progress(1, 1)
        return W, b
    threads = (os.cpu_count() or 1) if n_jobs == -1 else max(1, int(n_jobs))
    fit = _TRAINERS[trainer]
    y_present = np.searchsorted(present, y)
    if trainer in _PER_CLASS:
        Wp, bp = fit(X, y_present, present.size, C, random_state, threads, progress)
    else:
        Wp, bp = fit(X, y_present, present.size, C, random_state, threads)
        if progress is not None:
            progress(present.size, present.size)
    W[present] = Wp
    b[present] = bp
    return W, b


def _binary_loop(make: Callable[[], Any]) -> Callable[..., LinearModel]:
    def fit(
        X: np.ndarray, y: np.ndarray, n: int, C: float, seed: int | None, threads: int = 1,
        progress: StepFn | None = None,
    ) -> LinearModel:
        finished = itertools.count(1)  # next() is atomic under the GIL

        def one(c: int) -> tuple[np.ndarray, float]:
            est = make()
            est.set_params(C=C, random_state=seed)
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")  # convergence chatter; results stay usable
                est.fit(X, (y == c).astype(np.int64))
            if progress is not None:
                progress(next(finished), n)
            return est.coef_.ravel(), float(np.ravel(est.intercept_)[0])

        if threads > 1:
            with ThreadPoolExecutor(max_workers=threads) as pool:
                rows = list(pool.map(one, range(n)))
        else:
            rows = [one(c) for c in range(n)]
        return np.stack([r[0] for r in rows]), np.array([r[1] for r in rows])

    return fit


def _make_logreg() -> object:
    from sklearn.linear_model import LogisticRegression

    # LIBLINEAR -s 0 defaults, as in the paper's code: eps = 0.01.
    return LogisticRegression(solver="liblinear", intercept_scaling=1.0, max_iter=200, tol=0.01)


def _make_svm() -> object:
    from sklearn.svm import LinearSVC

    # LIBLINEAR -s 2 default stopping tolerance (eps = 0.01).
    return LinearSVC(loss="squared_hinge", dual="auto", max_iter=1000, tol=0.01)


def _fit_ridge(
    X: np.ndarray, y: np.ndarray, n: int, C: float, seed: int | None, threads: int = 1
) -> LinearModel:
    """Minimise ``½||W||² + C/2·||XW + b − Y||²`` in closed form (BLAS threads its own).

    The primal system is accumulated over row blocks, so a long route (a chunk classifier
    over a million frames) never holds its centred copy or the one-hot targets whole."""
    del seed, threads
    n_rows, n_cols = X.shape
    x_mean = X.mean(axis=0)
    y_mean = np.bincount(y, minlength=n) / n_rows
    lam = 1.0 / C
    if n_cols <= n_rows:  # primal: (XᵀX + λI) W = XᵀY
        A = np.zeros((n_cols, n_cols))
        B = np.zeros((n_cols, n))
        for s in range(0, n_rows, _RIDGE_BLOCK):
            Xc = X[s : s + _RIDGE_BLOCK] - x_mean
            Yc = np.zeros((Xc.shape[0], n))
            Yc[np.arange(Xc.shape[0]), y[s : s + _RIDGE_BLOCK]] = 1.0
            Yc -= y_mean
            A += Xc.T @ Xc
            B += Xc.T @ Yc
        A[np.diag_indices_from(A)] += lam
        W = _solve_psd(A, B)
    else:  # dual: W = Xᵀ (XXᵀ + λI)⁻¹ Y
        Xc = X - x_mean
        Yc = np.zeros((n_rows, n))
        Yc[np.arange(n_rows), y] = 1.0
        Yc -= y_mean
        K = Xc @ Xc.T
        K[np.diag_indices_from(K)] += lam
        W = Xc.T @ _solve_psd(K, Yc)
    b = y_mean - x_mean @ W
    return W.T.copy(), b


_RIDGE_BLOCK = 131072  # rows per block of the primal ridge system


def _solve_psd(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    from scipy import linalg

    return linalg.solve(A, B, assume_a="pos")


def _fit_torch(
    X: np.ndarray, y: np.ndarray, n: int, C: float, seed: int | None, threads: int = 1
) -> LinearModel:
    """One-vs-rest logistic loss for all classes at once, full-batch L-BFGS.

    On the CPU it uses ``threads`` intra-op threads (the estimator's ``n_jobs``), restored
    afterwards: torch's default of every core oversubscribes a machine shared with chunk
    processes or other work, which slowed a seconds-long fit to minutes here.
    """
    try:
        import torch
    except ImportError as exc:  # pragma: no cover - depends on the install
        raise InvalidParameterError(
            "trainer 'torch' needs PyTorch: pip install 'gridplace[torch]'"
        ) from exc
    previous = torch.get_num_threads()
    torch.set_num_threads(threads)
    try:
        return _lbfgs_torch(torch, X, y, n, C, seed)
    finally:
        torch.set_num_threads(previous)


def _lbfgs_torch(
    torch: Any, X: np.ndarray, y: np.ndarray, n: int, C: float, seed: int | None
) -> LinearModel:
    device = torch.device("cuda" if torch.cuda.is_available() else "cpu")
    gen = torch.Generator(device="cpu")
    gen.manual_seed(0 if seed is None else int(seed))
    Xt = torch.as_tensor(X, dtype=torch.float32, device=device)
    Yt = torch.zeros((X.shape[0], n), dtype=torch.float32, device=device)
    Yt[torch.arange(X.shape[0], device=device), torch.as_tensor(y, device=device)] = 1.0
    W = (0.01 * torch.randn((X.shape[1], n), generator=gen)).to(device).requires_grad_(True)
    b = torch.zeros(n, device=device, requires_grad=True)
    reg = 1.0 / (2.0 * C * X.shape[0])  # the logreg objective divided by C·N
    opt = torch.optim.LBFGS(
        [W, b], lr=1.0, max_iter=300, tolerance_grad=1e-6, line_search_fn="strong_wolfe"
    )
    loss_fn = torch.nn.BCEWithLogitsLoss(reduction="sum")

    def closure() -> torch.Tensor:
        opt.zero_grad()
        loss = loss_fn(Xt @ W + b, Yt) / (n * X.shape[0]) + reg * (W * W).sum() / n
        loss.backward()
        return loss

    opt.step(closure)
    return (
        W.detach().T.cpu().numpy().astype(np.float64),
        b.detach().cpu().numpy().astype(np.float64),
    )


_PER_CLASS = frozenset({"logreg", "svm"})  # one binary problem per class: progress per class
_TRAINERS: dict[str, Callable[..., LinearModel]] = {
    "logreg": _binary_loop(_make_logreg),
    "svm": _binary_loop(_make_svm),
    "ridge": _fit_ridge,
    "torch": _fit_torch,
    "prototype": fit_prototypes,
}

"""The ``prototype`` trainer: each class's weight row is the mean direction of its rows.

``W[c] = m_c / ‖m_c‖`` with ``m_c`` the mean of the training rows labelled ``c``, and bias 0,
so on L2-normalised rows (the projection front-end) a class scores the cosine between the
query and its class mean. Closed form, one pass over the rows; no regularisation, so ``C``
is ignored. The scores are cosines in ``[−1, 1]``: the classifier's ``temperature`` turns
them into log-probabilities (:mod:`service.encoding.calibration`).
"""

from __future__ import annotations

import numpy as np

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
    from scipy import sparse

    onehot = sparse.csr_matrix((np.ones(y.shape[0]), (y, np.arange(y.shape[0]))),
                               shape=(n, y.shape[0]))  # fmt: skip
    sums = np.asarray(onehot @ X, dtype=np.float64)
    norms = np.sqrt(np.einsum("ij,ij->i", sums, sums))[:, None]
    return sums / np.maximum(norms, _MIN_NORM), np.zeros(n)

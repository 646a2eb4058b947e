"""Input checks shared by every estimator (``.npy`` files are read by :mod:`service.npyfile`)."""

from __future__ import annotations

import numpy as np

from service.errors import (
    DimensionMismatchError,
    EmptyInputError,
    InvalidInputError,
    NonFiniteInputError,
)


def check_descriptors(
    X: object,
    n_features: int | None = None,
    min_rows: int = 1,
    what: str = "descriptors",
) -> np.ndarray:
    """Return ``X`` as a finite 2-D float64 array, or raise a precise error.

    A single 1-D descriptor is accepted where ``n_features`` is known and matches.
    """
    try:
        arr = np.asarray(X)
    except (ValueError, TypeError) as exc:
        raise InvalidInputError(f"{what}: not a rectangular numeric array ({exc})") from exc
    if arr.dtype == object or not (
        np.issubdtype(arr.dtype, np.number) or np.issubdtype(arr.dtype, np.bool_)
    ) or np.issubdtype(arr.dtype, np.complexfloating):
        raise InvalidInputError(f"{what}: must be real numbers, got dtype {arr.dtype}")
    if arr.ndim == 1 and n_features is not None and arr.shape[0] == n_features:
        arr = arr[None, :]
    if arr.ndim != 2:
        raise DimensionMismatchError(
            f"{what}: must be a 2-D array (rows = frames), got {arr.ndim} dimension(s)",
            shape=list(arr.shape),
        )
    if arr.shape[0] == 0 or arr.shape[1] == 0:
        raise EmptyInputError(f"{what}: empty (shape {arr.shape})")
    if arr.shape[0] < min_rows:
        raise InvalidInputError(
            f"{what}: at least {min_rows} rows needed, got {arr.shape[0]}", rows=arr.shape[0]
        )
    if n_features is not None and arr.shape[1] != n_features:
        raise DimensionMismatchError(
            f"{what}: {arr.shape[1]} columns, but the model expects {n_features}",
            expected=n_features,
            got=arr.shape[1],
        )
    arr = np.asarray(arr, dtype=np.float64)
    if not np.isfinite(arr).all():
        bad = np.argwhere(~np.isfinite(arr))[0]
        raise NonFiniteInputError(
            f"{what}: NaN or infinite values (first at row {bad[0]}, column {bad[1]})",
            row=int(bad[0]),
            column=int(bad[1]),
        )
    return arr

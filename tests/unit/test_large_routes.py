"""Long SYNTHETIC routes in bounded memory: the block-wise generator and training from a
read-only memory map (what ``gridplace bench scale`` does with a million frames)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from service.encoding import ChunkedPlaceEncoder
from service.encoding.chunk_training import check_route
from service.encoding.synthetic import route_queries, write_route
from service.errors import NonFiniteInputError


def test_write_route_is_smooth_unit_scaled_and_deterministic(tmp_path: Path) -> None:
    X = write_route(tmp_path / "a.npy", 70_000, 8, seed=3)  # crosses generator blocks
    assert isinstance(X, np.memmap) and X.dtype == np.float32 and X.shape == (70_000, 8)
    assert not X.flags.writeable
    A = np.asarray(X, dtype=np.float64)
    assert 0.9 < A.std(axis=0).mean() < 1.2  # smoothed part ≈ unit variance, plus frame noise
    neighbours = np.mean(np.sum(A[1:] * A[:-1], axis=0) / np.sum(A * A, axis=0))
    assert neighbours > 0.8  # neighbouring frames look alike
    jump = np.abs(A[32768] - A[32767]).mean()  # a block boundary is no seam
    assert jump < 2 * np.abs(np.diff(A[30000:32000], axis=0)).mean()
    np.testing.assert_array_equal(write_route(tmp_path / "b.npy", 70_000, 8, seed=3), X)
    Q = route_queries(X, np.array([5, 60_000]), 0.3, seed=1)
    assert Q.shape == (2, 8) and 0.1 < np.abs(Q - A[[5, 60_000]]).mean() < 0.5


def test_a_memory_mapped_route_trains_like_the_array(tmp_path: Path) -> None:
    X = write_route(tmp_path / "r.npy", 4000, 16, region_length=500, seed=2)
    assert check_route(X) is X  # validated in blocks, not copied to float64
    params: dict[str, Any] = {"n_chunks": 4, "trainer": "ridge", "n_jobs": 1}
    a = ChunkedPlaceEncoder(**params).fit(X)
    b = ChunkedPlaceEncoder(**params).fit(np.asarray(X))
    Q = route_queries(X, np.arange(0, 4000, 7), 0.3)
    np.testing.assert_array_equal(a.predict(Q), b.predict(Q))
    assert a.score(Q, np.arange(0, 4000, 7), tolerance=5) > 0.05  # chance: 11 / 4000


def test_a_non_finite_row_in_a_mapped_route_is_named(tmp_path: Path) -> None:
    path = tmp_path / "bad.npy"
    X = np.lib.format.open_memmap(path, mode="w+", dtype=np.float32, shape=(70_000, 4))
    X[:] = 1.0
    X[69_999, 2] = np.nan
    X.flush()
    with pytest.raises(NonFiniteInputError, match="NaN"):
        check_route(np.load(path, mmap_mode="r"))

"""The bounded ``.npy``/``.npz`` reader of uploads: exactly ``np.load(...).astype(float32)`` for
every numeric array it accepts, a precise error for everything else, and no allocation beyond
the budget. Arrays are random (hypothesis)."""

from __future__ import annotations

import io

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from service.core.array_upload import BLOCK_BYTES, read_npy_descriptors, read_npz_descriptors
from service.errors import (
    DimensionMismatchError,
    NonFiniteInputError,
    PayloadTooLargeError,
    UnsafeFileError,
)

DTYPES = st.sampled_from(["<f4", ">f8", "<f2", "<i8", "|u1", ">i2", "|b1"])


def _saved(arr: np.ndarray) -> io.BytesIO:
    buf = io.BytesIO()
    np.save(buf, arr, allow_pickle=False)
    buf.seek(0)
    return buf


@st.composite
def arrays(draw: st.DrawFn) -> np.ndarray:
    dtype = np.dtype(draw(DTYPES))
    shape = draw(st.tuples(st.integers(2, 40), st.integers(1, 30)))
    elements = st.floats(-1e4, 1e4, width=16) if dtype.kind == "f" else None
    arr = draw(hnp.arrays(dtype, shape, elements=elements))
    return np.asfortranarray(arr) if draw(st.booleans()) else arr


@settings(max_examples=150, deadline=None)
@given(arrays())
def test_reads_exactly_what_numpy_loads(arr: np.ndarray) -> None:
    got = read_npy_descriptors(_saved(arr), "x", budget_bytes=1 << 30)
    want = np.load(_saved(arr), allow_pickle=False).astype(np.float32)
    assert got.dtype == np.float32 and got.flags.c_contiguous
    np.testing.assert_array_equal(got, want)


@settings(max_examples=60, deadline=None)
@given(arrays(), st.data())
def test_a_budget_below_the_float32_size_is_refused_before_reading(arr: np.ndarray, data: st.DataObject) -> None:
    need = arr.size * max(4, arr.dtype.itemsize)
    budget = data.draw(st.integers(0, need - 1))
    with pytest.raises(PayloadTooLargeError, match="upload limit"):
        read_npy_descriptors(_saved(arr), "x", budget_bytes=budget)


@settings(max_examples=60, deadline=None)
@given(arrays(), st.data())
def test_a_truncated_file_is_refused(arr: np.ndarray, data: st.DataObject) -> None:
    raw = _saved(arr).getvalue()
    cut = data.draw(st.integers(0, len(raw) - 1))
    with pytest.raises(UnsafeFileError):
        read_npy_descriptors(io.BytesIO(raw[:cut]), "x", budget_bytes=1 << 30)


def test_rows_larger_than_a_block_and_lines_of_a_fortran_array() -> None:
    wide = np.random.default_rng(0).random((3, BLOCK_BYTES // 4 + 7)).astype(np.float32)
    np.testing.assert_array_equal(read_npy_descriptors(_saved(wide), "x", 1 << 30), wide)
    tall = np.asfortranarray(np.random.default_rng(1).random((BLOCK_BYTES // 8 + 5, 3)))
    np.testing.assert_array_equal(read_npy_descriptors(_saved(tall), "x", 1 << 30),
                                  tall.astype(np.float32))  # fmt: skip


@pytest.mark.parametrize(("arr", "error", "needle"), [
    (np.array([{"a": 1}, None], dtype=object), UnsafeFileError, "pickled"),
    (np.zeros(5, dtype=[("a", "<f4")]), UnsafeFileError, "numeric"),
    (np.zeros((2, 2), dtype=np.complex64), UnsafeFileError, "numeric"),
    (np.zeros(6), DimensionMismatchError, "2-D"),
    (np.zeros((2, 3, 4)), DimensionMismatchError, "2-D"),
    (np.array([[1.0, np.nan], [0, 0]]), NonFiniteInputError, "row 0, column 1"),
    (np.asfortranarray([[0.0, 0.0], [0.0, 1e300]]), NonFiniteInputError, "row 1, column 1"),
])  # fmt: skip
def test_what_is_refused_and_why(arr: np.ndarray, error: type[Exception], needle: str) -> None:
    buf = io.BytesIO()
    np.save(buf, arr, allow_pickle=True)
    buf.seek(0)
    with pytest.raises(error, match=needle):
        read_npy_descriptors(buf, "x", budget_bytes=1 << 30)


def test_npz_reads_the_descriptors_member_only() -> None:
    X = np.random.default_rng(2).random((20, 5))
    buf = io.BytesIO()
    np.savez_compressed(buf, aaa=np.zeros((10**5, 100), np.uint8), descriptors=X)
    buf.seek(0)
    got = read_npz_descriptors(buf, "r.npz", budget_bytes=1 << 20)  # aaa: 40 MB as float32
    np.testing.assert_array_equal(got, X.astype(np.float32))
    empty = io.BytesIO()
    np.savez(empty)
    with pytest.raises(Exception, match="holds no array"):
        read_npz_descriptors(io.BytesIO(empty.getvalue()), "e.npz", 1 << 20)

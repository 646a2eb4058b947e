"""Every bad-input class gets a precise exception from the one error hierarchy."""

from __future__ import annotations

import io
import pickle
from pathlib import Path

import numpy as np
import pytest

from service.encoding import ChunkedPlaceEncoder, PhaseEncoder, load_npy
from service.encoding.synthetic import SyntheticRoute
from service.errors import (
    DimensionMismatchError,
    EmptyInputError,
    GridplaceError,
    InvalidInputError,
    InvalidParameterError,
    NonFiniteInputError,
    NotFittedError,
    UnsafeFileError,
)


@pytest.fixture(scope="module")
def fitted(tiny_route: SyntheticRoute) -> PhaseEncoder:
    return PhaseEncoder(trainer="ridge").fit(tiny_route.reference)


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_non_finite_training_data(bad: float, tiny_route: SyntheticRoute) -> None:
    X = tiny_route.reference.copy()
    X[5, 3] = bad
    with pytest.raises(NonFiniteInputError, match="row 5, column 3"):
        PhaseEncoder().fit(X)


def test_non_finite_query(fitted: PhaseEncoder, tiny_route: SyntheticRoute) -> None:
    Q = tiny_route.query[:3].copy()
    Q[1, 0] = np.nan
    with pytest.raises(NonFiniteInputError):
        fitted.predict(Q)


def test_wrong_dimensionality(fitted: PhaseEncoder, tiny_route: SyntheticRoute) -> None:
    with pytest.raises(DimensionMismatchError, match="expects 24"):
        fitted.predict(tiny_route.query[:, :10])
    with pytest.raises(DimensionMismatchError):
        fitted.predict(np.zeros((2, 3, 4)))
    with pytest.raises(DimensionMismatchError):
        PhaseEncoder().fit(np.zeros(10))
    # a single 1-D descriptor of the right size is one query
    assert fitted.predict(tiny_route.query[0]).shape == (1,)


def test_too_few_frames() -> None:
    with pytest.raises(InvalidInputError, match="at least 2 rows"):
        PhaseEncoder().fit(np.zeros((1, 8)))
    with pytest.raises(EmptyInputError):
        PhaseEncoder().fit(np.zeros((0, 8)))


def test_fewer_frames_than_chunks(tiny_route: SyntheticRoute) -> None:
    with pytest.raises(InvalidParameterError, match="too few"):
        ChunkedPlaceEncoder(n_chunks=100).fit(tiny_route.reference)


def test_periods_whose_product_is_too_small(tiny_route: SyntheticRoute) -> None:
    with pytest.raises(InvalidParameterError, match="smaller than the number of frames"):
        PhaseEncoder(periods=(5, 5)).fit(tiny_route.reference)


@pytest.mark.parametrize("rho", [0.0, 1.01, -1.0])
def test_rho_outside_range(rho: float, tiny_route: SyntheticRoute) -> None:
    with pytest.raises(InvalidParameterError, match="rho"):
        PhaseEncoder(rho=rho).fit(tiny_route.reference)


@pytest.mark.parametrize(
    "params",
    [{"trainer": "xgboost"}, {"decode": "viterbi"}, {"dtype": "int4"}, {"gamma": 0.5}, {"C": 0.0},
     {"n_patterns": 50}],
)
def test_other_invalid_parameters(params: dict, tiny_route: SyntheticRoute) -> None:
    with pytest.raises(InvalidParameterError):
        PhaseEncoder(**params).fit(tiny_route.reference)


def test_non_numeric_data() -> None:
    with pytest.raises(InvalidInputError, match="real numbers"):
        PhaseEncoder().fit(np.array([["a", "b"], ["c", "d"]]))
    with pytest.raises(InvalidInputError):
        PhaseEncoder().fit([[1.0, 2.0], [3.0]])


def test_not_fitted() -> None:
    with pytest.raises(NotFittedError):
        PhaseEncoder().predict(np.zeros((1, 4)))


def test_pickled_npy_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "evil.npy"
    np.save(path, np.array([{"a": 1}], dtype=object), allow_pickle=True)
    with pytest.raises(UnsafeFileError, match="pickled"):
        load_npy(path)
    raw = tmp_path / "raw.npy"
    raw.write_bytes(pickle.dumps(np.zeros(3)))
    with pytest.raises(UnsafeFileError, match="not a .npy file: it looks like a Python pickle"):
        load_npy(raw)


def _npy_header(shape: tuple[int, ...]) -> bytes:
    buf = io.BytesIO()
    np.save(buf, np.zeros(shape, np.float32))
    return buf.getvalue()[:128]  # the header alone, no data


@pytest.mark.parametrize(("content", "needle"), [
    (b"0.1,0.2,0.3\n0.4,0.5,0.6\n", "not a .npy file: it looks like text with delimited numbers"),
    (b"just some notes\n", "not a .npy file: it looks like a text file"),
    (b"\x89PNG\r\n\x1a\n" + bytes(30), "not a .npy file: it looks like an image"),
    (b"\x93NUMPY\x01\x00" + b"\x10\x00{'descr': '<f4',", "not a valid .npy file: corrupt header"),
    (_npy_header((4, 2)), "truncated: its header declares shape (4, 2)"),
])  # fmt: skip
def test_what_a_file_is_is_said_before_anything_is_loaded(tmp_path: Path, content: bytes,
                                                          needle: str) -> None:  # fmt: skip
    path = tmp_path / "x.npy"
    path.write_bytes(content)
    with pytest.raises(UnsafeFileError, match=needle.replace("(", r"\(").replace(")", r"\)")):
        load_npy(path)


def test_the_header_is_checked_before_the_data_is_read(tmp_path: Path) -> None:
    path = tmp_path / "big.npy"
    np.save(path, np.zeros((50, 3), np.float32))
    seen = []

    def refuse(header: object) -> None:
        seen.append(header)
        raise InvalidParameterError("no")

    with pytest.raises(InvalidParameterError):
        load_npy(path, check=refuse)
    assert seen[0].shape == (50, 3) and seen[0].nbytes == 600  # type: ignore[attr-defined]


def test_non_numeric_npy_and_missing_file(tmp_path: Path) -> None:
    path = tmp_path / "s.npy"
    np.save(path, np.array(["x", "y"]))
    with pytest.raises(UnsafeFileError, match="numeric"):
        load_npy(path)
    with pytest.raises(InvalidInputError, match="no such file"):
        load_npy(tmp_path / "absent.npy")


def test_every_error_maps_to_http_and_grpc() -> None:
    for cls in (NonFiniteInputError, DimensionMismatchError, InvalidParameterError, UnsafeFileError):
        err = cls("x")
        assert isinstance(err, GridplaceError) and isinstance(err, ValueError)
        assert err.http_status == 400 and err.grpc_status == "INVALID_ARGUMENT"
    assert NotFittedError("x").http_status == 409

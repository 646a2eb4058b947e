"""z-scoring with the route's statistics refuses values that would overflow float32."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from service.encoding import ChunkedPlaceEncoder, PhaseEncoder
from service.encoding.normalization import Normalizer
from service.encoding.synthetic import SyntheticRoute
from service.errors import InputOverflowError, NonFiniteInputError

F32_MAX = float(np.finfo(np.float32).max)


@settings(max_examples=60, deadline=None)
@given(
    d=st.integers(1, 40),
    scale=st.floats(1e-3, 1e3),
    z=st.floats(-1e40, 1e40, allow_nan=False),
    col=st.integers(0, 39),
)
def test_refused_exactly_beyond_float32_max_over_d(d: int, scale: float, z: float, col: int) -> None:
    norm = Normalizer(mean=np.zeros(d, np.float32), scale=np.full(d, scale, np.float32))
    col %= d
    X = np.zeros((3, d))
    X[2, col] = z * float(norm.scale[0])
    limit = F32_MAX / d
    z_actual = X[2, col] / float(norm.scale[0])
    if abs(z_actual) <= limit:
        Z = norm.transform(X)
        assert np.isfinite(Z).all() and np.abs(Z).max() <= limit
    else:
        with pytest.raises(InputOverflowError, match=f"row 2, column {col} ") as info:
            norm.transform(X)
        assert isinstance(info.value, NonFiniteInputError)  # callers catching non-finite see it


@pytest.mark.parametrize("model", [PhaseEncoder(trainer="ridge"),
                                   ChunkedPlaceEncoder(n_chunks=2, trainer="ridge")])  # fmt: skip
@pytest.mark.parametrize("value", [1e308, -1e308, F32_MAX])
def test_models_refuse_all_extreme_queries(model: PhaseEncoder, value: float,
                                           tiny_route: SyntheticRoute) -> None:  # fmt: skip
    model.fit(tiny_route.reference)
    Q = np.full((2, tiny_route.reference.shape[1]), value)
    with pytest.raises(InputOverflowError, match="overflow once normalised"):
        model.localize(Q)
    assert model.localize(tiny_route.query[:4]).index.shape == (4,)  # ordinary queries answer

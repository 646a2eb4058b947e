"""The work budget counts what a query's search reads: every frame for the flat scan and for a
drive's filter, the list centroids and probed lists for a map with an inverted file."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from service.core.localization import LocalizationService
from service.core.model_store import LoadedModel
from service.encoding import PhaseEncoder
from service.encoding.synthetic import smooth_route
from service.errors import PayloadTooLargeError

N = 3000


def _loaded(search: str) -> LoadedModel:
    model = PhaseEncoder(n_patterns=1, rho=1.0, trainer="prototype", code="residue",
                         n_components=16, dtype="int8", temperature=0.028,
                         search=search, nprobe=20,  # below the default's floor: a part
                         ).fit(smooth_route(N, 32, seed=2).reference)  # fmt: skip
    return LoadedModel("m", 1, model, info=None, extractor_config=None)  # type: ignore[arg-type]


def _check(loaded: LoadedModel, budget_units: int, rows: int, states: int = 0) -> None:
    svc = SimpleNamespace(settings=SimpleNamespace(max_request_work=budget_units / 1e6))
    LocalizationService.check_work(svc, loaded, rows, states)  # type: ignore[arg-type]


def test_an_inverted_file_map_counts_the_rows_its_search_reads() -> None:
    loaded = _loaded("ivf")
    ivf = loaded.model.ivf_
    assert ivf is not None and ivf.nprobe < ivf.nlist
    scored = loaded.frames_per_query
    sizes = np.diff(ivf.offsets)
    assert scored == ivf.nlist + np.sort(sizes)[-ivf.nprobe:].sum() < N
    budget = 10 * scored * 8
    _check(loaded, budget, 10)  # within: the rows 10 queries read
    with pytest.raises(PayloadTooLargeError) as err:
        _check(loaded, budget, 11)
    assert f"11 frames × {scored} rows scored per query × (8)" in err.value.message
    with pytest.raises(PayloadTooLargeError) as err:  # a drive's filter reads every frame
        _check(loaded, budget, 1, states=16)
    assert f"1 frames × {N} map frames × (8 + 16 states)" in err.value.message


def test_a_flat_map_counts_every_frame() -> None:
    loaded = _loaded("flat")
    assert loaded.model.ivf_ is None and loaded.frames_per_query == N
    _check(loaded, 10 * N * 8, 10)
    with pytest.raises(PayloadTooLargeError) as err:
        _check(loaded, 10 * N * 8, 11)
    assert f"11 frames × {N} map frames × (8)" in err.value.message

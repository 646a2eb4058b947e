"""How many rows of a batch the service localizes at a time: scores within a bounded block,
and with an inverted file far larger blocks than a flat scan of the same route."""

from __future__ import annotations

import tracemalloc

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from service.core.localization import MIN_BLOCK_ROWS, SCORE_BLOCK_BYTES, block_rows
from service.core.model_store import LoadedModel
from service.encoding import PhaseEncoder
from service.encoding.inverted_file import InvertedFile
from service.encoding.ivf_scan import batch_entries_per_query, search
from service.encoding.synthetic import smooth_route


def _loaded(search_mode: str, route: np.ndarray) -> LoadedModel:
    model = PhaseEncoder(n_patterns=1, rho=1.0, trainer="prototype", code="residue",
                         n_components=24, dtype="int8", temperature=0.028, search=search_mode,
                         nlist=30, nprobe=5).fit(route)  # fmt: skip
    return LoadedModel(map="m", version=1, model=model, info=None,  # type: ignore[arg-type]
                       extractor_config=None)  # fmt: skip


def test_an_inverted_file_holds_its_pairs_entries_not_every_frames() -> None:
    route = smooth_route(900, 48, seed=3).reference
    flat, ivf = _loaded("flat", route), _loaded("ivf", route)
    assert flat.entries_per_query == 900
    assert ivf.entries_per_query == batch_entries_per_query(5, 48) == 16 * 5 + 48
    assert block_rows(ivf.entries_per_query) > block_rows(flat.entries_per_query)


@given(entries=st.integers(1, 10**10))
def test_a_block_is_the_most_rows_whose_scores_fit(entries: int) -> None:
    rows = block_rows(entries)
    assert rows >= MIN_BLOCK_ROWS
    assert rows == MIN_BLOCK_ROWS or rows * entries * 8 <= SCORE_BLOCK_BYTES
    assert (rows + 1) * entries * 8 > SCORE_BLOCK_BYTES


class _Rows:
    def __init__(self, n: int, m: int, seed: int) -> None:
        rng = np.random.default_rng(seed)
        self.weight = rng.integers(-127, 128, (n, m)).astype(np.int8)
        self.rowscale: np.ndarray | None = rng.uniform(0.001, 0.01, n).astype(np.float32)
        self.bias = rng.normal(0, 0.1, n)
        self.beta = 20.0


def _peak(ivf: InvertedFile, rows: _Rows, Z: np.ndarray) -> int:
    tracemalloc.start()
    try:
        search(ivf, rows, Z)
        return tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


def test_the_batch_scans_memory_grows_within_its_entries_per_query() -> None:
    """What a query adds to a batch scan's peak stays within the entries the service counts."""
    m, nprobe = 16, 6
    rows = _Rows(3000, m, seed=5)
    ivf = InvertedFile.fit(rows.weight, rows.rowscale, 60, nprobe=nprobe, seed=5)
    Z = np.random.default_rng(6).standard_normal((6000, m)).astype(np.float32)
    small, large = _peak(ivf, rows, Z[:1000]), _peak(ivf, rows, Z)
    per_query = (large - small) / 5000
    assert 0 < per_query <= 8 * batch_entries_per_query(nprobe, m)

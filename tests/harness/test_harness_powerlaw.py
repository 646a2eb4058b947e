"""The power-law fit behind the storage-scaling exponents, and the sweep helpers."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from service.errors import InvalidParameterError
from service.harness.config import BenchConfig
from service.harness.exp_retrieval import pr_curve
from service.harness.exp_storage import summarize
from service.harness.powerlaw import fit_power_law
from service.harness.sizes import geometric_sizes


@settings(max_examples=40, deadline=None)
@given(a=st.floats(-2.0, 2.0), c=st.floats(1e-3, 1e3), n=st.integers(2, 12))
def test_exact_points_give_back_exponent_and_constant(a: float, c: float, n: int) -> None:
    x = np.geomspace(100, 100_000, n)
    fit = fit_power_law(x, c * x**a)
    assert fit.a == pytest.approx(a, abs=1e-6)
    assert fit.c == pytest.approx(c, rel=1e-5)
    assert fit.n_points == n


def test_noisy_points_recover_a_known_sublinear_exponent() -> None:
    rng = np.random.default_rng(0)
    x = np.geomspace(100, 90_000, 30)
    y = 42.0 * x**0.37 * np.exp(rng.normal(0, 0.05, x.size))
    fit = fit_power_law(x, y)
    assert fit.a == pytest.approx(0.37, abs=0.03)
    assert 0.95 < fit.r2 <= 1.0
    assert fit.predict(1000.0) == pytest.approx(42.0 * 1000.0**0.37, rel=0.15)


@pytest.mark.parametrize(
    ("x", "y"),
    [
        ([100], [5]),
        ([100, 100], [5, 6]),
        ([100, 200], [0, 6]),
        ([-1, 200], [1, 6]),
        ([1, 2, 3], [1, 2]),
    ],
)
def test_fit_rejects_unusable_points(x: list[float], y: list[float]) -> None:
    with pytest.raises(InvalidParameterError):
        fit_power_law(x, y)


def test_geometric_sizes_span_the_route() -> None:
    sizes = geometric_sizes(100, 3576, 5)
    assert sizes[0] == 100 and sizes[-1] == 3576
    assert sizes == sorted(set(sizes))
    assert geometric_sizes(100, 50, 5) == [50]


def test_pr_curve_of_a_perfect_ranking() -> None:
    conf = np.array([0.9, 0.8, 0.7, 0.2, 0.1])
    correct = np.array([True, True, True, False, False])
    pr = pr_curve(conf, correct)
    assert pr["recall_at_100_precision"] == pytest.approx(0.6)
    assert pr["average_precision"] == pytest.approx(0.6)
    assert pr["precision"][-1] == pytest.approx(0.6) and pr["recall"][-1] == pytest.approx(0.6)
    assert pr_curve(conf[::-1].copy(), correct)["recall_at_100_precision"] == 0.0


def test_summarize_keeps_the_cheapest_setting_reaching_each_target() -> None:
    cfg = BenchConfig(identical_targets=(0.9,), cross_targets=(0.5,))
    points = []
    for n in (100, 400, 1600):
        for scale, prec in ((1.0, 0.95), (0.5, 0.85), (2.0, 0.99)):
            points.append({"method": "gridplace", "N": n, "params": {"rho": scale},
                           "paper_bytes": scale * 10 * n**0.5, "actual_bytes": scale * 5 * n**0.5,
                           "identical": {"0": prec}, "cross": {"5": prec - 0.4}})  # fmt: skip
    ident, cross = summarize(points, cfg)
    best = ident["methods"]["gridplace"]["best"]
    assert [b["params"]["rho"] for b in best] == [1.0, 1.0, 1.0]
    assert ident["methods"]["gridplace"]["fit_paper"]["a"] == pytest.approx(0.5)
    assert [b["params"]["rho"] for b in cross["methods"]["gridplace"]["best"]] == [1.0] * 3
    assert cross["target"] == 0.5 and cross["tolerance"] == 5


def test_the_papers_form_gives_exactly_linear_storage_about_one_half() -> None:
    """Exact NN on 2,048 float64 columns (8·2048·N bytes), N = 100…10,000: c·N^a says 1,
    the paper's MB = N^a form says ≈ 0.53."""
    from service.harness.powerlaw import fit_paper_form

    n = np.arange(100, 10_001, 100, dtype=np.float64)
    storage = 8 * 2048 * n
    assert fit_power_law(n, storage).a == pytest.approx(1.0, abs=1e-9)
    form = fit_paper_form(n, storage)
    assert form.a == pytest.approx(0.533, abs=0.01)
    assert form.n_points == n.size and form.rmse_mb > 0


@settings(max_examples=30, deadline=None)
@given(a=st.floats(0.1, 1.5))
def test_the_papers_form_recovers_its_own_curves(a: float) -> None:
    from service.harness.powerlaw import MB, fit_paper_form

    x = np.geomspace(100, 1_000_000, 8)
    fit = fit_paper_form(x, MB * x**a)
    assert fit.a == pytest.approx(a, abs=1e-6)
    assert fit.predict_bytes(1e4) == pytest.approx(MB * 1e4**a, rel=1e-5)

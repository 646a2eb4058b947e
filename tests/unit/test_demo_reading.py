"""The demo's one-line verdict: honest in both directions, with the figures it compares."""

from __future__ import annotations

from typing import Any

from service.cli.demo_reading import RESULTS_DOC, reading, verdict


def _results(ours: float, nn: float, drive: float = 0.99, nn_drive: float = 0.97) -> dict[str, Any]:
    def p(x: float) -> dict[str, Any]:
        return {"precision_at": {"5": x}}

    return {
        "gridplace/cross-season": p(ours), "exact NN/cross-season": p(nn),
        "gridplace/identical": {**p(1.0), "footprint_bytes": 1_000},
        "exact NN/identical": {**p(1.0), "footprint_bytes": 40_000},
        "gridplace/cross-season drive": p(drive), "exact NN/cross-season drive": p(nn_drive),
        "gridplace/cross-season as sent": p(ours / 2), "exact NN/cross-season as sent": p(nn / 2),
    }  # fmt: skip


def test_below_exact_nn_says_how_much_is_kept() -> None:
    line = verdict(_results(0.3, 0.4, 0.5, 1.0))
    assert line is not None
    assert "keeps 75% of exact NN's" in line and "(30.0% against 40.0%)" in line
    assert "50% of it as a drive (50.0% against 100.0%)" in line and "2.5% of its storage" in line


def test_at_or_above_exact_nn_never_claims_more_than_measured() -> None:
    line = verdict(_results(0.44, 0.41))
    assert line is not None and "matches or beats" in line and "(44.0% against 41.0%)" in line
    assert "as much or more as a drive (99.0% against 97.0%)" in line


def test_reading_ends_with_the_results_doc() -> None:
    text = reading(_results(0.3, 0.4), 3576)
    assert text.splitlines()[-1].endswith(f"{RESULTS_DOC} (Across conditions)")
    assert "B per frame" in text and verdict({}) is None


def test_the_adaptation_line_gives_both_models_before_and_after() -> None:
    text = reading(_results(0.5, 0.4), 3576)
    assert "gridplace 25.0% → 50.0%, exact NN 20.0% → 40.0%" in text

"""The harness end to end on a tiny SYNTHETIC route: it runs, and every output is well formed."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from PIL import Image
from typer.testing import CliRunner

from service.cli import app
from service.errors import InvalidParameterError
from service.harness import BenchConfig, run_paper, synthetic_dataset
from service.harness.methods import MethodSpec

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def tiny_config(**overrides: Any) -> BenchConfig:
    base = {
        "storage_n_min": 60, "storage_n_points": 3, "storage_rhos": (0.5, 1.0), "storage_ks": (2, 3),
        "timing_n_min": 100, "timing_n_points": 2, "timing_trainers": ("ridge", "logreg"),
        "timing_yu_trainers": ("ridge",), "slow_trainer_max_n": 150, "single_query_repeats": 3,
        "pattern_ks": (2, 3), "chunk_n_frames": 1200, "chunk_n_features": 24, "chunk_n_chunks": 3,
        "chunk_n_queries": 300, "retrieval_gridplace": ((2, 0.5),), "retrieval_pq_m": (8,),
    }  # fmt: skip
    return BenchConfig.quick(**{**base, **overrides})


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory) -> tuple[dict[str, Any], Path]:
    out = tmp_path_factory.mktemp("paper")
    results = run_paper(synthetic_dataset(300, 32, seed=0), out, tiny_config(), argv=["test"])
    return results, out


def _assert_png(path: Path) -> None:
    assert path.read_bytes()[:8] == PNG_SIGNATURE
    with Image.open(path) as im:
        im.verify()


def test_every_experiment_writes_json_markdown_and_a_valid_png(run: tuple[dict, Path]) -> None:
    _results, out = run
    on_disk = json.loads((out / "results.json").read_text())
    assert set(on_disk) >= {"dataset", "context", "config", "experiments", "figures",
                            "elapsed_seconds"}  # fmt: skip
    assert set(on_disk["experiments"]) == {"storage", "timing", "patterns", "chunking", "retrieval"}
    for name, fig in on_disk["figures"].items():
        assert fig == f"{name}.png"
        _assert_png(out / fig)
    report = (out / "report.md").read_text()
    for heading in ("## 1. Storage scaling", "## 2. Training and query time", "## 3. Precision vs",
                    "## 4. Chunking at scale", "## 5. Against retrieval"):  # fmt: skip
        assert heading in report
    assert report.count("|---|") >= 5 and "![storage scaling](storage.png)" in report


def test_outputs_are_labelled_synthetic_with_machine_and_date(run: tuple[dict, Path]) -> None:
    results, out = run
    assert results["dataset"]["synthetic"] is True
    assert "SYNTHETIC" in results["dataset"]["label"]
    assert "SYNTHETIC DATA" in (out / "report.md").read_text()
    assert results["experiments"]["chunking"]["dataset"]["synthetic"] is True
    ctx = results["context"]
    assert ctx["machine"]["cores"] >= 1 and ctx["date"].endswith("UTC") and ctx["command"] == "test"
    assert results["config"]["trainer"] == "ridge" and results["config"]["dtype"] == "float32"


def test_storage_results_hold_fits_and_both_byte_counts(run: tuple[dict, Path]) -> None:
    storage = run[0]["experiments"]["storage"]
    assert storage["sizes"][-1] == 300
    point = storage["points"][0]
    assert point["paper_bytes"] > 0 and point["actual_bytes"] > 0
    assert len(storage["targets"]) == 4
    nn = storage["targets"][0]["methods"]["exact_nn"]  # 99 % identical: exact NN reaches it
    assert nn["fit_paper"]["a"] == pytest.approx(1.0, abs=0.1)


def test_timing_respects_the_slow_trainer_cap(run: tuple[dict, Path]) -> None:
    rows = run[0]["experiments"]["timing"]["rows"]
    assert {r["N"] for r in rows if r["trainer"] == "logreg"} == {100}
    assert {r["N"] for r in rows if r["trainer"] == "ridge" and r["method"] == "gridplace"} == {
        100,
        300,
    }
    assert all(r["train_seconds"] >= 0 and r["query_us_single"] > 0 for r in rows)


def test_chunking_and_retrieval_are_scored(run: tuple[dict, Path]) -> None:
    chunking = run[0]["experiments"]["chunking"]
    assert chunking["dataset"]["N"] == 1200 and chunking["n_queries_scored"] == 300
    assert set(chunking["models"]) == {"chunked", "unchunked"}
    ch = chunking["models"]["chunked"]
    assert len(ch["chunk_sizes"]) == 3 and sum(ch["chunk_sizes"]) == 1200
    for cond in ("identical", "noisy"):
        assert 0.0 <= ch[cond]["chunk_accuracy"] <= 1.0
        precisions = [ch[cond]["precision"][str(t)] for t in chunking["tolerances"]]
        assert precisions == sorted(precisions)  # wider tolerance never lowers precision
    rows = {r["method"] for r in run[0]["experiments"]["retrieval"]["rows"]}
    assert {"gridplace", "exact_nn"} <= rows
    for r in run[0]["experiments"]["retrieval"]["rows"]:
        pr = r["cross"]["pr"]
        assert len(pr["precision"]) == len(pr["recall"]) and 0 <= pr["average_precision"] <= 1


def test_column_subset_baseline_charges_its_mask() -> None:
    ds = synthetic_dataset(80, 40, seed=2)
    full = MethodSpec("exact_nn", rho=1.0).build().fit(ds.reference)
    half = MethodSpec("exact_nn", rho=0.5).build().fit(ds.reference)
    fp_full, fp_half = full.footprint(), half.footprint()
    assert "column_mask" in fp_half.components and "column_mask" not in fp_full.components
    assert fp_half.components["column_mask"].actual_bytes == 5
    assert fp_half.paper_bytes < fp_full.paper_bytes
    assert np.array_equal(half.localize(ds.reference).index[:5], np.arange(5))


def test_cli_runs_a_subset_on_a_dataset_folder(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    data = tmp_path / "route"
    data.mkdir()
    ref = rng.normal(size=(120, 16)).astype(np.float32)
    np.save(data / "reference.npy", ref)
    np.save(data / "query.npy", ref + 0.1 * rng.normal(size=ref.shape).astype(np.float32))
    out = tmp_path / "out"
    result = CliRunner().invoke(app, ["bench", "paper", "--dataset", str(data), "--out", str(out),
                                      "--experiments", "patterns",
                                      "--markdown", str(tmp_path / "docs" / "R.md")])  # fmt: skip
    assert result.exit_code == 0, result.output
    results = json.loads((out / "results.json").read_text())
    assert results["dataset"]["synthetic"] is False and results["dataset"]["N"] == 120
    assert list(results["experiments"]) == ["patterns"]
    _assert_png(out / "patterns.png")
    assert "![patterns](../out/patterns.png)" in (tmp_path / "docs" / "R.md").read_text()


def test_cli_names_a_bad_dataset(tmp_path: Path) -> None:
    result = CliRunner().invoke(app, ["bench", "paper", "--dataset", str(tmp_path / "missing"),
                                      "--out", str(tmp_path / "o")])  # fmt: skip
    assert result.exit_code == 2
    assert "does not exist" in " ".join(result.output.split())


def test_presets_and_bad_experiment_names() -> None:
    quick, full = BenchConfig.quick(), BenchConfig.full()
    assert quick.preset == "quick" and full.preset == "full"
    assert len(full.storage_rhos) > len(quick.storage_rhos)
    assert full.chunk_n_frames >= 89_000 and quick.chunk_n_frames >= 89_000
    assert quick.uses_torch() and not BenchConfig.quick(experiments=("patterns",)).uses_torch()
    with pytest.raises(InvalidParameterError, match="unknown experiments"):
        BenchConfig.quick(experiments=("storage", "vibes"))


def test_redraw_remakes_figures_and_report_from_the_json(
    run: tuple[dict, Path], tmp_path: Path
) -> None:
    _, out = run
    copy = tmp_path / "copy"
    copy.mkdir()
    (copy / "results.json").write_bytes((out / "results.json").read_bytes())
    result = CliRunner().invoke(app, ["bench", "paper", "--redraw", "--out", str(copy)])
    assert result.exit_code == 0, result.output
    for name in ("storage", "timing", "patterns", "chunking", "retrieval"):
        _assert_png(copy / f"{name}.png")
    assert (copy / "report.md").read_text() == (out / "report.md").read_text()
    missing = CliRunner().invoke(app, ["bench", "paper", "--redraw", "--out", str(tmp_path)])
    assert missing.exit_code == 2 and "no results.json" in missing.output


def test_retrieval_runs_without_faiss(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    import service.harness.exp_retrieval as retrieval

    monkeypatch.setattr(retrieval, "faiss_available", lambda: False)
    cfg = tiny_config(experiments=("retrieval",))
    results = run_paper(synthetic_dataset(300, 32, seed=1), tmp_path, cfg)
    rows = results["experiments"]["retrieval"]["rows"]
    assert {r["method"] for r in rows} == {"gridplace", "exact_nn"}
    assert "faiss is not installed, so PQ is absent" in (tmp_path / "report.md").read_text()


def test_cli_without_a_dataset_uses_a_labelled_synthetic_route(tmp_path: Path) -> None:
    out = tmp_path / "out"
    result = CliRunner().invoke(app, ["bench", "paper", "--out", str(out), "--experiments",
                                      "patterns", "--synthetic-frames", "200",
                                      "--synthetic-features", "16"])  # fmt: skip
    assert result.exit_code == 0, result.output
    assert "SYNTHETIC" in result.output
    results = json.loads((out / "results.json").read_text())
    assert results["dataset"]["synthetic"] is True and results["dataset"]["N"] == 200
    assert (out / "report.md").read_text().count("SYNTHETIC") >= 2

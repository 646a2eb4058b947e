"""Every front door says what ships: ``pyproject.toml``'s description, ``gridplace --help``, the
demo's banner, the README's top and docs/RESULTS.md's opening name the default preset as it is,
and the figures they quote are the ones the benchmark JSON files hold."""

from __future__ import annotations

import json
import subprocess
import sys
import tomllib
from pathlib import Path

from service.cli.pitch import DEMO_BANNER, DESCRIBED_DEFAULT, FIGURES, HELP, SUMMARY
from service.encoding.presets import DEFAULT_PRESET

ROOT = Path(__file__).resolve().parents[2]
BENCH = ROOT / "docs" / "benchmarks"


def flat(text: str) -> str:
    return " ".join(text.split())


def test_the_pitch_describes_the_default_preset() -> None:
    assert DESCRIBED_DEFAULT == DEFAULT_PRESET, "the default changed: update service/cli/pitch.py"
    for text in (HELP, DEMO_BANNER):
        assert f"`{DEFAULT_PRESET}`" in text and "linear" in text


def test_pyproject_and_help_carry_the_summary() -> None:
    meta = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    assert meta["description"] == SUMMARY
    out = subprocess.run([sys.executable, "-m", "service.cli", "--help"], capture_output=True,
                         text=True, timeout=60, check=True)  # fmt: skip
    assert flat(SUMMARY) in flat(out.stdout) and "grows linearly" in flat(out.stdout)


def test_the_readme_opens_with_what_ships() -> None:
    readme = (ROOT / "README.md").read_text()
    top = flat(readme[: readme.index("## Two commands on a fresh machine")])
    assert flat(SUMMARY) in top
    assert f"**`{DEFAULT_PRESET}`** (default)" in top and "linearly" in top
    assert "`drive`" in top and f"{FIGURES['drive_drive']}" in top  # the drive preset's row
    for key in ("robust_single", "exact_nn_single", "nn_pca256_single", "robust_adapted",
                "robust_drive", "robust_storage_pct", "paper_single"):  # fmt: skip
        assert f"{FIGURES[key]}" in top, key
    # the paper's promise is not the product's: no claim of a few classifiers per route
    assert "instead of every frame's descriptor" not in top


def test_results_open_with_the_product_summary() -> None:
    results = (ROOT / "docs" / "RESULTS.md").read_text()
    first = results[: results.index("\n## ", results.index("\n## ") + 1)]
    assert first.count("\n") < 60, "the summary fits on one screen"
    assert f"`{DEFAULT_PRESET}`" in first and "nn-pca256" in first
    assert "frontier.png" in first


def test_the_figures_are_the_measured_ones() -> None:
    cli = json.loads((BENCH / "cli-defaults-nordland-2026-12-01.json").read_text())
    adapted = json.loads((BENCH / "cli-defaults-adapted-nordland-2026-12-01.json").read_text())
    quality = json.loads((ROOT / "docs" / "results" / "quality" / "quality.json").read_text())
    cnn = next(s for s in quality["sets"] if s["dataset"]["name"] == "lite0-b4")
    cross = {r["method"]: r["drives"]["all"] for r in cnn["protocols"]["cross"]["results"]}

    def pct(x: float) -> float:
        return round(100 * x, 1)

    assert FIGURES["robust_single"] == pct(cli["gridplace"]["single_p5"])
    assert FIGURES["exact_nn_single"] == pct(cli["exact_nn"]["single_p5"])
    drive = json.loads((BENCH / "cli-drive-nordland-stop-probability-2026-12-06.json").read_text())
    assert FIGURES["robust_drive"] == pct(drive["robust"]["sequence_precision"])
    assert FIGURES["drive_drive"] == pct(drive["drive"]["sequence_precision"])
    assert FIGURES["drive_single"] == pct(drive["drive_as_sent"]["precision"])
    assert FIGURES["drive_code_pct"] == pct(drive["ratios"]["drive_code_bytes_vs_robust"])
    assert FIGURES["robust_storage_pct"] == pct(cli["ratios"]["storage_vs_exact_nn"])
    assert FIGURES["robust_adapted"] == pct(adapted["gridplace"]["adapted"]["single_p5"])
    assert FIGURES["nn_pca256_single"] == pct(cross["nn-pca256"]["single"]["5"])
    assert FIGURES["paper_single"] == pct(cross["paper"]["single"]["5"])
    assert FIGURES["residue_single"] == pct(cross["residue"]["single"]["5"])
    assert FIGURES["residue_drive"] == pct(cross["residue"]["sequence"]["5"])

"""What a new user meets first on the command line: ``gridplace train``'s output check and
default trainer, and ``serve --help``'s settings list. Routes are SYNTHETIC."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from service.cli import app, model_commands
from service.encoding import default_trainer, read_manifest
from service.encoding.synthetic import smooth_route
from service.settings import Settings

runner = CliRunner()


def gridplace(*args: str | Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "service.cli", *map(str, args)],
                          capture_output=True, text=True, timeout=300, check=False)  # fmt: skip


@pytest.fixture(scope="module")
def ref(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("first-run") / "ref.npy"
    np.save(path, smooth_route(200, 16, seed=4).reference, allow_pickle=False)
    return path


def test_train_into_an_existing_directory_fails_before_training(
    ref: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    out = tmp_path / "model"
    out.mkdir()
    (out / "keep.txt").write_text("mine")
    res = gridplace("train", ref, "--out", out, "--trainer", "ridge")
    assert res.returncode == 2, res.stdout + res.stderr
    assert "error [conflict]" in res.stderr and str(out) in res.stderr
    assert "already exists" in res.stderr and "saved" not in res.stdout
    assert [p.name for p in out.iterdir()] == ["keep.txt"]
    # and the refusal comes before any model is built or fitted
    monkeypatch.setattr(model_commands, "build_model", _must_not_train)
    r = runner.invoke(app, ["train", str(ref), "--out", str(out)])
    assert r.exit_code == 2 and "already exists" in r.output


def _must_not_train(*args: object) -> None:
    raise AssertionError("training started although --out cannot be written")


def test_train_into_an_unwritable_place_fails_before_training(
    ref: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(model_commands, "build_model", _must_not_train)
    (tmp_path / "a-file").write_text("x")
    r = runner.invoke(app, ["train", str(ref), "--out", str(tmp_path / "a-file" / "model")])
    assert r.exit_code == 2 and "is not a directory" in r.output
    r = runner.invoke(app, ["train", str(ref), "--out", "/proc/gridplace-model"])
    assert r.exit_code == 2 and "not writable" in r.output


def test_train_defaults_to_the_default_trainer(
    ref: Path, tmp_path: Path
) -> None:
    r = runner.invoke(app, ["train", str(ref), "--out", str(tmp_path / "default")])
    assert r.exit_code == 0, r.output
    assert read_manifest(tmp_path / "default")["params"]["trainer"] == default_trainer()
    assert f"trainer={default_trainer()}" in r.output
    help_text = runner.invoke(app, ["train", "--help"], terminal_width=200).output
    assert f"(default: {default_trainer()})" in help_text


def test_serve_help_lists_one_setting_per_line() -> None:
    r = runner.invoke(app, ["serve", "--help"])
    assert r.exit_code == 0
    lines = [ln.strip() for ln in r.output.splitlines()]
    rows = [i for i, ln in enumerate(lines) if ln.startswith("GRIDPLACE_")]
    assert len(rows) == len(Settings.model_fields)
    assert all(lines[rows[0] : rows[-1]]), "blank lines between the settings"

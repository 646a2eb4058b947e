"""``gridplace client`` as a separate process writing into a pipe, against the real server of
conftest.py: the preset each upload was trained with, recorded and shown, and tables and
lines that a pipe or a log receives whole (SYNTHETIC data)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from client_helpers import TOKEN, wait_serving

from service.api.process import ServerProcess
from service.client import GridplaceClient, Job
from service.encoding import ModelParams

pytestmark = pytest.mark.slow
Route = tuple[np.ndarray, np.ndarray]


def _cli(server: ServerProcess, *args: str) -> subprocess.CompletedProcess[str]:
    """The command as a user's script runs it: stdout is a pipe, no COLUMNS set."""
    env = {k: v for k, v in os.environ.items() if k not in ("COLUMNS", "LINES")}
    env.update(GRIDPLACE_URL=server.url, GRIDPLACE_ADMIN_TOKEN=TOKEN)
    return subprocess.run([sys.executable, "-m", "service.cli", "client", *args], env=env,
                          capture_output=True, text=True, timeout=120, check=False)  # fmt: skip


def test_upload_help_names_every_trainer_and_the_preset(server: ServerProcess) -> None:
    out = _cli(server, "upload", "--help")
    assert out.returncode == 0, out.stderr
    text = " ".join(out.stdout.split())
    assert "--preset" in text and "prototype" in text
    for name in ("paper", "ridge", "robust", "residue"):
        assert name in text


def test_each_upload_records_the_preset_it_was_trained_with(
    server: ServerProcess, gp: GridplaceClient, route: Route, tmp_path: Path
) -> None:
    ref = tmp_path / "ref.npy"
    np.save(ref, route[0][:120], allow_pickle=False)
    cases = {  # upload options → the preset the version must record
        "pre-default": ([], "robust"),
        "pre-named": (["--preset", "residue"], "residue"),
        "pre-ridge": (["--trainer", "ridge"], "paper"),  # an option of the paper's code
    }
    for name, (args, want) in cases.items():
        out = _cli(server, "upload", name, str(ref), *args, "--wait", "--wait-timeout", "120")
        assert out.returncode == 0, out.stdout + out.stderr
        (version,) = gp.list_versions(name)
        assert version.params["encoder_preset"] == want, (name, version.params)
    # the ridge upload is the ridge preset, not a ridge over the default's projection
    ridge = gp.list_versions("pre-ridge")[0].params
    named = ModelParams(encoder_preset="ridge").model_dump(mode="json")
    for key in ("trainer", "code", "n_patterns", "rho", "n_components", "dtype"):
        assert ridge[key] == named[key], key
    wait_serving(gp, "pre-default", 1)
    table = _cli(server, "versions", "pre-default")
    assert table.returncode == 0 and "robust" in table.stdout


def test_tables_and_lines_are_not_wrapped_into_a_pipe(server: ServerProcess, synth: Job) -> None:
    versions = _cli(server, "versions", "synth")
    assert versions.returncode == 0, versions.stderr
    assert "…" not in versions.stdout  # no cell squeezed into 80 columns
    created = synth.created_at.strftime("%Y-%m-%d")
    (row,) = [ln for ln in versions.stdout.splitlines() if "phase_encoder" in ln]
    assert created in row and "300" in row and "paper" in row  # one line, the preset shown
    jobs = _cli(server, "jobs", synth.id)
    assert jobs.returncode == 0, jobs.stderr
    assert "…" not in jobs.stdout and synth.id in jobs.stdout  # the whole 32-hex id
    (row,) = [ln for ln in jobs.stdout.splitlines() if synth.id in ln]
    assert "succeeded" in row and "synth" in row
    missing = _cli(server, "localize", "synth", "--npy", "/nonexistent/" + "d" * 90 + "/q.npy")
    assert missing.returncode == 2
    assert "/nonexistent/" + "d" * 90 + "/q.npy" in missing.stderr  # the path on one line

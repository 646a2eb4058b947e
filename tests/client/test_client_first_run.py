"""``gridplace client upload --wait`` says whether the new version serves, and the job answer
carries the fit's progress; against the real server of conftest.py (SYNTHETIC data)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from client_helpers import TOKEN
from typer.testing import CliRunner, Result

from service.api.process import ServerProcess
from service.cli import app
from service.client import GridplaceClient
from service.encoding import default_trainer

pytestmark = pytest.mark.slow
runner = CliRunner()


def _client(server: ServerProcess, *args: str) -> Result:
    env = {"GRIDPLACE_URL": server.url, "GRIDPLACE_ADMIN_TOKEN": TOKEN, "COLUMNS": "300"}
    return runner.invoke(app, ["client", *args], env=env)


def test_upload_wait_says_whether_the_version_is_active(
    server: ServerProcess, gp: GridplaceClient, route: tuple[np.ndarray, np.ndarray],
    tmp_path: Path,
) -> None:  # fmt: skip
    first, second = tmp_path / "v1.npy", tmp_path / "v2.npy"
    np.save(first, route[0], allow_pickle=False)
    np.save(second, route[0][:, ::-1].copy(), allow_pickle=False)  # another route, same width
    # no --trainer: the server's default; the first version of a map goes live by itself
    r = _client(server, "upload", "firstrun", str(first), "--wait")
    assert r.exit_code == 0, r.output
    assert "version 1 is active (served for map firstrun)" in r.output
    assert gp.get_version("firstrun", 1).params["trainer"] == default_trainer()
    r = _client(server, "upload", "firstrun", str(second), "--trainer", "ridge", "--wait")
    assert r.exit_code == 0, r.output
    out = " ".join(r.output.split())  # the console may wrap the long line
    assert "version 2 is NOT active (map firstrun serves version 1)" in out
    assert "activate it with: gridplace client activate firstrun 2" in out
    assert gp.get_map("firstrun").active_version == 1
    r = _client(server, "activate", "firstrun", "2")
    assert r.exit_code == 0 and gp.get_map("firstrun").active_version == 2


def test_a_finished_job_answer_carries_its_progress(
    server: ServerProcess, route: tuple[np.ndarray, np.ndarray], tmp_path: Path
) -> None:
    path = tmp_path / "p.npy"
    np.save(path, route[0][:120], allow_pickle=False)
    r = _client(server, "upload", "firstrun-progress", str(path), "--trainer", "ridge",
                "--chunks", "2", "--wait", "--json")  # fmt: skip
    assert r.exit_code == 0, r.output
    job = json.loads(r.output[r.output.index("{") :])
    progress = job["progress"]
    assert progress["fraction"] == 1.0
    assert set(progress["parts"]) == {"chunk_0", "chunk_1", "chunk_classifier"}
    assert all(p["done"] == p["total"] > 0 for p in progress["parts"].values())
    r = _client(server, "jobs", job["id"])
    assert r.exit_code == 0 and "100%" in r.output

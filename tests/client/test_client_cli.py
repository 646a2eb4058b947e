"""``gridplace client …`` against the real server of conftest.py (SYNTHETIC data, ridge)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from client_helpers import TOKEN, png, wait_serving
from typer.testing import CliRunner, Result

from service.api.process import ServerProcess, free_port
from service.cli import app
from service.client import GridplaceClient, Job

pytestmark = pytest.mark.slow
runner = CliRunner()
Route = tuple[np.ndarray, np.ndarray]


def _run(server: ServerProcess, *args: str, token: str | None = TOKEN) -> Result:
    env = {"GRIDPLACE_URL": server.url, "GRIDPLACE_ADMIN_TOKEN": token or "", "COLUMNS": "200"}
    return runner.invoke(app, ["client", *args], env=env)


def test_status_maps_versions(server: ServerProcess, synth: Job) -> None:
    r = _run(server, "status")
    assert r.exit_code == 0 and "alive, ready" in r.output and "synth v1" in r.output
    r = _run(server, "maps", "--json")
    assert r.exit_code == 0, r.output
    assert {m["name"]: m["active_version"] for m in json.loads(r.output)}["synth"] == 1
    r = _run(server, "maps")
    assert r.exit_code == 0 and "synth" in r.output
    r = _run(server, "versions", "synth", "--json")
    assert r.exit_code == 0, r.output
    assert json.loads(r.output)[0]["params"]["trainer"] == "ridge"
    r = _run(server, "versions", "synth")
    assert r.exit_code == 0 and "300" in r.output  # frames column


def test_localize_descriptors_and_images(server: ServerProcess, synth: Job, route: Route,
                                         gp: GridplaceClient, tmp_path: Path) -> None:  # fmt: skip
    queries = tmp_path / "q.npy"
    np.save(queries, route[1][:20], allow_pickle=False)
    want = gp.localize_batch("synth", route[1][5:9]).index
    r = _run(server, "localize", "synth", "--npy", str(queries), "--rows", "5:9", "--json")
    assert r.exit_code == 0, r.output
    assert json.loads(r.output)["index"] == want
    r = _run(server, "localize", "synth", "--npy", str(queries), "--rows", "5")
    assert r.exit_code == 0 and "synth v1: 1 query in" in r.output and str(want[0]) in r.output
    r = _run(server, "localize", "synth")
    assert r.exit_code == 2 and "exactly one of --npy or --image" in r.output
    image = tmp_path / "q.png"
    image.write_bytes(png(1))
    r = _run(server, "localize", "synth", "--image", str(image))
    assert (
        r.exit_code == 2 and "error [" in r.output and "extractor" in r.output
    )  # a descriptor map


def test_upload_wait_jobs_activate(server: ServerProcess, synth: Job, route: Route,
                                   gp: GridplaceClient, tmp_path: Path) -> None:  # fmt: skip
    path = tmp_path / "cli-route.npy"
    np.save(path, route[0], allow_pickle=False)
    r = _run(server, "upload", "cli", str(path), "--trainer", "ridge", "--periods", "20,15",
             "--idempotency-key", "cli-1", "-p", "random_state=3", "--wait", "--json")  # fmt: skip
    assert r.exit_code == 0, r.output
    job = json.loads(r.output[r.output.index("{") :])
    assert job["state"] == "succeeded" and job["version"] == 1
    assert gp.get_version("cli", 1).params["random_state"] == 3
    r = _run(server, "jobs", job["id"], "--json")
    assert r.exit_code == 0 and json.loads(r.output)[0]["id"] == job["id"]
    r = _run(server, "upload", "cli", str(path), "--trainer", "ridge", "--idempotency-key", "cli-2")
    assert r.exit_code == 0 and "gridplace client jobs" in r.output
    job2 = r.output.split("job ", 1)[1].split()[0]
    r = _run(server, "jobs", job2, "--wait")
    assert r.exit_code == 0 and "succeeded" in r.output
    r = _run(server, "activate", "cli", "2")
    assert r.exit_code == 0 and "version 2 is active" in r.output
    wait_serving(gp, "cli", 2)
    r = _run(server, "delete", "cli", "1")
    assert r.exit_code == 0 and "deleted" in r.output
    r = _run(server, "deactivate", "cli")
    assert r.exit_code == 0 and "out of service" in r.output


def test_errors_print_their_code_and_exit_2(
    server: ServerProcess, synth: Job, tmp_path: Path
) -> None:
    r = _run(server, "versions", "nope")
    assert r.exit_code == 2 and "error [not_found]:" in r.output
    r = _run(server, "maps", token="wrong")
    assert r.exit_code == 2 and "error [unauthorized]: invalid admin token" in r.output
    r = _run(server, "activate", "synth", "7")
    assert r.exit_code == 2 and "error [not_found]" in r.output
    r = _run(server, "upload", "x", str(tmp_path / "missing.npy"), "--trainer", "ridge")
    assert r.exit_code == 2 and "route file not found" in r.output
    r = _run(server, "upload", "x", str(tmp_path / "missing.npy"), "--periods", "a,b")
    assert r.exit_code == 2 and "--periods must be integers" in r.output
    r = _run(server, "upload", "x", str(tmp_path / "missing.npy"), "-p", "bogus=1")
    assert r.exit_code == 2 and "error [invalid_parameter]" in r.output and "bogus" in r.output
    r = _run(server, "upload", "x", str(tmp_path / "missing.npy"), "-p", "rho")
    assert r.exit_code == 2 and "KEY=VALUE" in r.output
    bad = tmp_path / "bad.npy"
    np.save(bad, np.full((30, 4), np.nan), allow_pickle=False)
    r = _run(server, "upload", "bad", str(bad), "--trainer", "ridge", "--wait")
    assert r.exit_code == 2 and "error [" in r.output  # refused at upload or failed job
    csv = tmp_path / "queries.csv"
    np.savetxt(csv, np.zeros((3, 4)), delimiter=",")
    r = _run(server, "localize", "synth", "--npy", str(csv))
    assert r.exit_code == 2 and "is not a .npy file" in r.output and "CSV" in r.output
    assert "pickled" not in r.output
    r = runner.invoke(app, ["client", "status", "--url", f"http://127.0.0.1:{free_port()}"])
    assert r.exit_code == 2 and "error [server_unreachable]" in r.output

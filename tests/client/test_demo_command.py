"""``gridplace demo`` as a real process: the table (--no-serve) and the served map with its
printed copy-paste examples actually working (SYNTHETIC route, the default preset)."""

from __future__ import annotations

import json
import os
import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from service.api.process import free_port
from service.bench.data import shared_data_dir
from service.client import GridplaceClient, ServerUnreachableError

pytestmark = pytest.mark.slow
DEMO = [sys.executable, "-m", "service.cli", "demo"]  # the default preset, as a newcomer runs it
ENV = {**os.environ, "PYTHONUNBUFFERED": "1", "COLUMNS": "160"}


def test_no_serve_prints_the_table_and_exits(tmp_path: Path) -> None:
    out = subprocess.run([*DEMO, "--no-serve", "--synthetic", "--frames", "300", "--out", str(tmp_path)],
                         check=False, capture_output=True, text=True, timeout=120, env=ENV)  # fmt: skip
    assert out.returncode == 0, out.stdout + out.stderr
    assert "SYNTHETIC" in out.stdout and "cross-season" in out.stdout and "exact NN" in out.stdout
    # the numbers come with a reading and a pointer to the measured results
    assert "a random guess gets" in out.stdout and "docs/RESULTS.md" in out.stdout
    # single frames and the drive through the sequence filter, beside exact NN, with storage
    assert "as a drive" in out.stdout and "as one drive" in out.stdout and "of its storage" in out.stdout
    # what ships, and where its gain comes from: exact NN in the default's own space beside it
    assert out.stdout.startswith("gridplace demo: the default preset `robust`")
    assert "nn-pca" in out.stdout and "where the gain comes from" in out.stdout
    assert "within ±k frames" in " ".join(out.stdout.split())  # P@k is defined
    (results,) = tmp_path.glob("*.results.json")
    assert set(json.loads(results.read_text())) >= {"gridplace/identical", "exact NN/cross-season",
                                                    "gridplace/cross-season drive",
                                                    "nn-pca/cross-season"}  # fmt: skip
    assert "curl" not in out.stdout and not (tmp_path / "registry.sqlite3").exists()


@pytest.mark.skipif(shared_data_dir() is None, reason="Nordland data not in ../shared/data")
def test_no_serve_on_a_slice_of_nordland(tmp_path: Path) -> None:
    out = subprocess.run([*DEMO, "--no-serve", "--frames", "200", "--out", str(tmp_path)],
                         check=False, capture_output=True, text=True, timeout=120, env=ENV)  # fmt: skip
    assert out.returncode == 0, out.stdout + out.stderr
    assert "Nordland summer→winter, 200 frames" in out.stdout


def test_options_of_the_paper_code_are_named_in_the_banner(tmp_path: Path) -> None:
    out = subprocess.run([*DEMO, "--no-serve", "--synthetic", "--frames", "200", "--trainer", "ridge",
                          "--out", str(tmp_path)], check=False, capture_output=True, text=True,
                         timeout=120, env=ENV)  # fmt: skip
    assert out.returncode == 0, out.stdout + out.stderr
    assert out.stdout.startswith("gridplace demo: preset `paper` (chosen by your options")
    assert "nn-pca" not in out.stdout  # no projection: no exact NN in its space to show


def test_bad_parameters_exit_2(tmp_path: Path) -> None:
    out = subprocess.run([*DEMO, "--no-serve", "--rho", "3", "--out", str(tmp_path)],
                         check=False, capture_output=True, text=True, timeout=60, env=ENV)  # fmt: skip
    assert out.returncode == 2 and "error [invalid_parameter]" in out.stderr


def _read_until(proc: subprocess.Popen[str], marker: str, timeout_s: float) -> list[str]:
    lines: list[str] = []
    deadline = time.monotonic() + timeout_s
    assert proc.stdout is not None
    while time.monotonic() < deadline:
        line = proc.stdout.readline()
        if not line:
            break
        lines.append(line.rstrip("\n"))
        if marker in line:
            return lines
    raise AssertionError("demo never printed its examples:\n" + "\n".join(lines))


def test_serve_publishes_the_map_and_its_examples_work(tmp_path: Path) -> None:
    port, data_dir = free_port(), tmp_path / "data"
    cmd = [*DEMO, "--synthetic", "--frames", "300", "--out", str(tmp_path / "artifacts"),
           "--data-dir", str(data_dir), "--port", str(port), "--grpc-port", "0"]  # fmt: skip
    env = {k: v for k, v in ENV.items() if k != "GRIDPLACE_ADMIN_TOKEN"}
    proc = subprocess.Popen(
        cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env
    )
    try:
        lines = _read_until(proc, "Ctrl-C stops the server", 120)
        start = next(i for i, ln in enumerate(lines) if ln.startswith("server check:"))
        answers = [ln for ln in lines[start:] if re.match(r"\s+frame\s+\d+ →\s+\d+\s+", ln)]
        assert len(answers) == 8, lines[start:]  # several frames, each right or wrong
        assert all(re.search(r"(within ±5|wrong by [\d,]+ frames), confidence", a) for a in answers)
        summary = next(ln for ln in lines[start:] if " of these 8, " in ln)
        assert re.search(r"\d+ of 100 evenly spaced frames .* within ±5 frames", summary), summary
        assert "calibrated softmax probability" in summary  # one digit: not "joint … digits"
        example = next(ln for ln in lines[start:] if "the examples below send frame" in ln)
        frame = int(re.search(r"send frame (\d+)", example).group(1))  # type: ignore[union-attr]
        answered = int(re.search(r"server answers (\d+)", example).group(1))  # type: ignore[union-attr]
        exports = {ln.split("=", 1)[0][len("export "):]: ln.split("=", 1)[1]
                   for ln in lines if ln.startswith("export ")}  # fmt: skip
        assert exports["GRIDPLACE_URL"] == f"http://127.0.0.1:{port}"
        token = exports["GRIDPLACE_ADMIN_TOKEN"]
        assert len(token) >= 32  # a fresh random token, never a default
        with GridplaceClient(exports["GRIDPLACE_URL"], token=token) as gp:
            assert gp.get_map("demo").serving_version == 1
            (version,) = gp.list_versions("demo")
            assert version.n_frames == 300 and "SYNTHETIC" in version.metrics["dataset"]
        commands = [ln for ln in lines if ln.startswith(("curl", "JOB_ID="))]
        assert not [ln for ln in commands if "<" in ln]  # no placeholder that breaks a paste
        if shutil.which("curl"):
            shell_env = {**env, **exports}
            for line in commands:
                run = subprocess.run(["bash", "-c", line], check=False, capture_output=True, text=True,
                                     env=shell_env, timeout=30)  # fmt: skip
                if line.startswith("JOB_ID="):  # the upload: its job id for the next lines
                    assert run.returncode == 0 and re.fullmatch(r"[0-9a-f]{32}\n", run.stdout), run
                    shell_env["JOB_ID"] = run.stdout.strip()
                    continue
                body = json.loads(run.stdout)
                failed = isinstance(body, dict) and isinstance(body.get("error"), str)
                assert run.returncode == 0 and not failed, (line, body)
                if "/v1/jobs/" in line:
                    assert body["id"] == shell_env["JOB_ID"] and "progress" in body
                if line.endswith("/v1/localize"):  # the example frame: the answer printed above
                    assert body["index"] == answered, (frame, body)
        assert any("grpc" in ln.lower() for ln in lines)
        proc.send_signal(signal.SIGINT)  # Ctrl-C
        assert proc.wait(timeout=30) == 0
        gone = GridplaceClient(exports["GRIDPLACE_URL"], timeout=2)
        with gone, pytest.raises(ServerUnreachableError):
            gone.health()  # the server went down with the demo
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()

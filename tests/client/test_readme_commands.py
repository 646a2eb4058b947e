"""The README's service commands, pasted into a shell against a real ``gridplace serve``: the
upload, the job, the JSON localize built from a real descriptor and the client's localize
(SYNTHETIC uint8 rows stand in for the Nordland files the README names)."""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from service.api.process import ServerProcess
from service.client import GridplaceClient
from service.encoding.synthetic import smooth_route

pytestmark = pytest.mark.slow
ROOT = Path(__file__).resolve().parents[2]
TOKEN = "readme-commands-admin-token"


def _service_block() -> list[str]:
    """The command lines of the README's first ``## The service`` code block, continuations
    joined, comments dropped."""
    text = (ROOT / "README.md").read_text()
    section = text[text.index("## The service") :]
    block = section[section.index("```bash") + len("```bash") : section.index("```", section.index("```bash") + 7)]
    lines, current = [], ""
    for raw in block.strip().splitlines():
        line = raw.split("  #")[0].rstrip() if not raw.lstrip().startswith("#") else ""
        if not line:
            continue
        current += line.rstrip("\\").strip() + " " if line.endswith("\\") else line.strip()
        if not line.endswith("\\"):
            lines.append(current)
            current = ""
    return lines


@pytest.mark.skipif(shutil.which("curl") is None, reason="the README's commands use curl")
def test_the_readme_service_commands_run_as_written(tmp_path: Path) -> None:
    lines = _service_block()
    shared = tmp_path / "shared" / "data" / "nordland-64x32"
    shared.mkdir(parents=True)
    route = smooth_route(600, 64, seed=3)  # SYNTHETIC, stored as uint8 like the Nordland files
    scale = lambda X: np.clip(127 + 40 * X, 0, 255).astype(np.uint8)  # noqa: E731
    np.save(shared / "reference.npy", scale(route.reference))
    np.save(shared / "query.npy", scale(route.query))
    work = tmp_path / "work"  # the README's ../shared/data is beside it
    work.mkdir()
    with ServerProcess(tmp_path / "data", env={"GRIDPLACE_ADMIN_TOKEN": TOKEN}) as srv:
        srv.wait_ready(60)
        port = srv.url.rsplit(":", 1)[1]
        env = {**os.environ, "GRIDPLACE_ADMIN_TOKEN": TOKEN, "GRIDPLACE_URL": srv.url,
               "PATH": f"{Path(sys.executable).parent}:{os.environ.get('PATH', '')}"}  # fmt: skip
        shell = [ln.replace("127.0.0.1:8080", f"127.0.0.1:{port}") for ln in lines
                 if not ln.startswith(("export ", "gridplace serve"))]  # fmt: skip
        variables = "\n".join(ln for ln in shell if re.match(r"[A-Z]+=[^$(]", ln))  # REF=, QRY=
        commands = [ln for ln in shell if not re.match(r"[A-Z]+=[^$(]", ln)]

        def bash(line: str, job: str = "") -> subprocess.CompletedProcess[str]:
            script = f"set -e -o pipefail\n{variables}\nJOB_ID={job}\n{line}"
            return subprocess.run(["bash", "-c", script], cwd=work, env=env, capture_output=True,
                                  text=True, timeout=120, check=False)  # fmt: skip

        upload = bash(commands[0] + "\necho $JOB_ID")
        assert commands[0].startswith("JOB_ID=") and upload.returncode == 0, upload
        job_id = upload.stdout.strip()
        assert re.fullmatch(r"[0-9a-f]{32}", job_id), upload
        with GridplaceClient(srv.url, token=TOKEN) as gp:
            assert gp.wait_for_job(job_id, timeout=180).state == "succeeded"
            assert gp.get_map("nordland").active_version == 1
        for line in commands[1:]:
            run = bash(line, job_id)
            assert run.returncode == 0, (line, run.stdout, run.stderr)
            if line.endswith("/v1/localize"):
                assert isinstance(json.loads(run.stdout)["index"], int), run.stdout
            elif "/v1/jobs/" in line:
                assert json.loads(run.stdout)["state"] == "succeeded"
            elif line.startswith("gridplace client localize"):
                assert "nordland v1: 10 queries" in run.stdout, run.stdout
        assert any(ln.endswith("/v1/localize") for ln in commands)

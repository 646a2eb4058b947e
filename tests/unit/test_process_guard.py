"""The session-end process check, on a real pytest session that leaks two processes."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import process_tree
import pytest

LEAKY = '''
import subprocess, sys

SLEEPER = [sys.executable, "-c", "import time; time.sleep(120)  # leaked-%s"]


def test_leaks_a_child():
    subprocess.Popen(SLEEPER[:2] + [SLEEPER[2] % "child"])


def test_leaks_an_orphan():
    # its parent exits at once: the sleeper is orphaned (reparented to the session)
    starter = f"import subprocess; subprocess.Popen({SLEEPER[:2] + [SLEEPER[2] % 'orphan']!r})"
    subprocess.run([sys.executable, "-c", starter], check=True)
'''


@pytest.mark.skipif(not process_tree.supported(), reason="reads /proc (Linux)")
def test_a_session_that_leaves_processes_behind_fails_and_kills_them(tmp_path: Path) -> None:
    (tmp_path / "test_leaky.py").write_text(LEAKY)
    tests_dir = str(Path(__file__).resolve().parents[1])
    path = os.pathsep.join([tests_dir, os.environ.get("PYTHONPATH", "")])
    env = {**os.environ, "PYTHONPATH": path}
    run = subprocess.run(
        [sys.executable, "-m", "pytest", "-q", "-p", "process_guard", "-p", "no:cacheprovider",
         "--rootdir", str(tmp_path), str(tmp_path / "test_leaky.py")],
        check=False, capture_output=True, text=True, env=env, timeout=120, cwd=tmp_path,
    )  # fmt: skip
    out = run.stdout + run.stderr
    assert run.returncode == 1, out  # both tests passed; the session failed
    assert "2 passed" in out and "processes left behind by the test session" in out, out
    assert "leaked-child" in out and "leaked-orphan" in out, out
    mine = process_tree.descendants(os.getpid())
    assert not [p for p in mine if "leaked-" in process_tree.describe(p)]  # the session killed them

"""``gridplace train`` on several traversals of a route (SYNTHETIC routes)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from service.encoding.synthetic import smooth_route


def run(*args: str | Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "service.cli", *map(str, args)],
        capture_output=True, text=True, timeout=300,
    )  # fmt: skip


@pytest.fixture(scope="module")
def root(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("cli-traversals")
    route = smooth_route(160, 24, seed=5)  # SYNTHETIC
    np.save(root / "summer.npy", route.reference)
    np.save(root / "winter.npy", route.query)
    np.save(root / "winter_half.npy", route.query[::2])
    np.save(root / "narrow.npy", route.query[:, :20])
    np.save(root / "all_places.npy", np.arange(160))
    np.save(root / "half_places.npy", np.arange(0, 160, 2))
    return root


def test_train_on_two_traversals_records_them(root: Path) -> None:
    res = run("train", root / "summer.npy", root / "winter.npy", "--out", root / "m2",
              "--trainer", "ridge")  # fmt: skip
    assert res.returncode == 0, res.stderr
    assert "traversals=2" in res.stdout
    manifest = json.loads((root / "m2" / "manifest.json").read_text())
    assert manifest["n_traversals"] == 2 and manifest["n_places"] == 160
    res = run("evaluate", root / "m2", root / "winter.npy", "--tolerance", "5", "--json")
    assert res.returncode == 0, res.stderr
    assert json.loads(res.stdout)["n"] == 160


def test_train_with_a_place_index_per_file(root: Path) -> None:
    res = run("train", root / "summer.npy", root / "winter_half.npy", "--places",
              root / "all_places.npy", "--places", root / "half_places.npy", "--out",
              root / "mp", "--trainer", "ridge", "--chunks", "2")  # fmt: skip
    assert res.returncode == 0, res.stderr
    manifest = json.loads((root / "mp" / "manifest.json").read_text())
    assert manifest["n_traversals"] == 2 and manifest["n_places"] == 160


@pytest.mark.parametrize(
    "args, message",
    [
        (["summer.npy", "narrow.npy"],
         "traversal 2 (narrow.npy) has 20 columns but traversal 1 (summer.npy) has 24"),
        (["summer.npy", "winter_half.npy"],
         "traversal 2 (winter_half.npy) has 80 rows but traversal 1 (summer.npy) has 160"),
        (["summer.npy", "winter_half.npy", "--places", "all_places.npy"],
         "2 descriptor file(s) need 2 --places file(s)"),
        (["summer.npy", "winter_half.npy", "--places", "all_places.npy", "--places",
          "all_places.npy"], "has 160 entries but its traversal has 80 rows"),
    ],
)  # fmt: skip
def test_bad_traversals_exit_2_naming_the_problem(root: Path, args: list[str], message: str) -> None:
    out = root / "refused"
    res = run("train", *[root / a if a.endswith(".npy") else a for a in args], "--out", out,
              "--trainer", "ridge")  # fmt: skip
    assert res.returncode == 2, res.stdout + res.stderr
    assert "error [" in res.stderr and message in " ".join(res.stderr.split())
    assert not out.exists()

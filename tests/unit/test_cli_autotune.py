"""``gridplace train --budget-bytes / --target-precision`` (SYNTHETIC routes, CliRunner):
the choice is made on the validation split given (or the held-out last traversal), fits the
budget, is recorded in the manifest, and impossible requests exit 2 naming the problem."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from service.cli import app
from service.encoding import read_manifest
from service.encoding.synthetic import smooth_route


@pytest.fixture(scope="module")
def root(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("cli-autotune")
    route = smooth_route(160, 24, seed=5)  # SYNTHETIC
    np.save(root / "summer.npy", route.reference)
    np.save(root / "winter.npy", route.query)
    return root


def train(*args: str | Path) -> tuple[int, str]:
    res = CliRunner().invoke(app, ["train", *map(str, args)], env={"COLUMNS": "200"})
    return res.exit_code, res.output


def test_budget_is_met_and_recorded(root: Path) -> None:
    code, out = train(root / "summer.npy", "--out", root / "free", "--budget-bytes", "100000000",
                      "--validation", root / "winter.npy")  # fmt: skip
    assert code == 0, out
    free = read_manifest(root / "free")["extra"]["autotune"]
    sizes = sorted(c["actual_bytes"] for c in free["candidates"])
    budget = sizes[len(sizes) // 2]
    code, out = train(root / "summer.npy", "--out", root / "tight", "--budget-bytes", str(budget),
                      "--validation", root / "winter.npy")  # fmt: skip
    assert code == 0, out
    man = read_manifest(root / "tight")
    tuned = man["extra"]["autotune"]
    chosen = next(c for c in tuned["candidates"] if c["name"] == tuned["chosen"])
    assert chosen["actual_bytes"] <= budget and man["footprint"]["actual_bytes"] <= budget
    assert f"chose {tuned['chosen']}:" in out and tuned["budget_bytes"] == budget  # names intact
    fits = [c for c in tuned["candidates"] if c["actual_bytes"] <= budget]
    assert chosen["precision"] == max(c["precision"] for c in fits)


def test_target_on_a_held_out_traversal(root: Path) -> None:
    code, out = train(root / "summer.npy", root / "winter.npy", "--out", root / "held",
                      "--target-precision", "0.01", "--validation-tolerance", "10")  # fmt: skip
    assert code == 0, out
    man = read_manifest(root / "held")
    assert man["extra"]["autotune"]["target_precision"] == 0.01 and "held out" in out
    assert "traversals=2" in out  # the chosen configuration trains on every traversal


@pytest.mark.parametrize(("extra", "message"), [
    ((), "--validation"),
    (("--validation", "{root}/winter.npy", "--budget-bytes", "1"), "no candidate fits"),
    (("--validation-truth", "{root}/winter.npy"), "--validation-truth needs --validation"),
])  # fmt: skip
def test_impossible_requests_exit_2(root: Path, tmp_path: Path, extra: tuple[str, ...],
                                    message: str) -> None:  # fmt: skip
    args = [a.format(root=root) for a in extra]
    if "--budget-bytes" not in args:
        args += ["--budget-bytes", "100000"]
    code, out = train(root / "summer.npy", "--out", tmp_path / "m", *args)
    assert code == 2 and message in out, out
    assert not (tmp_path / "m").exists()

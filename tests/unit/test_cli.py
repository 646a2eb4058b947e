"""The ``gridplace`` command line on .npy files (SYNTHETIC routes), as a user runs it."""

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
        capture_output=True,
        text=True,
        timeout=300,
    )


@pytest.fixture(scope="module")
def files(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("cli")
    route = smooth_route(300, 32, seed=11)  # SYNTHETIC
    np.save(root / "ref.npy", route.reference)
    np.save(root / "query.npy", route.query.astype(np.float64))
    np.save(root / "gt.npy", np.arange(300))
    return {"root": root, "ref": root / "ref.npy", "query": root / "query.npy", "gt": root / "gt.npy"}


def test_train_evaluate_localize(files: dict[str, Path]) -> None:
    model = files["root"] / "model"
    res = run("train", files["ref"], "--out", model, "--patterns", "2", "--rho", "0.5",
              "--trainer", "ridge")
    assert res.returncode == 0, res.stderr
    assert (model / "manifest.json").is_file()

    res = run("evaluate", model, files["query"], "--tolerance", "5", "--json")
    assert res.returncode == 0, res.stderr
    out = json.loads(res.stdout)
    assert out["n"] == 300 and out["precision"] > 0.3
    assert out["footprint_bytes"] > 0 and out["paper_bytes"] > 0

    res = run("evaluate", model, files["query"], "--tolerance", "5", "--json",
              "--ground-truth", files["gt"])
    assert json.loads(res.stdout)["precision"] == out["precision"]

    pred = files["root"] / "pred.npy"
    res = run("localize", model, files["query"], "--out", pred)
    assert res.returncode == 0, res.stderr
    indices = np.load(pred)
    assert indices.shape == (300,) and indices.dtype == np.int64
    assert np.mean(np.abs(indices - np.arange(300)) <= 5) == pytest.approx(out["precision"])


def test_chunked_training_from_the_cli(files: dict[str, Path]) -> None:
    model = files["root"] / "chunked"
    res = run("train", files["ref"], "--out", model, "--chunks", "3", "--trainer", "ridge",
              "--n-jobs", "2", "--dtype", "int8")
    assert res.returncode == 0, res.stderr
    man = json.loads((model / "manifest.json").read_text())
    assert man["kind"] == "chunked_encoder" and man["dtype"] == "int8"


@pytest.mark.parametrize(
    "args,needle",
    [
        (["--preset", "paper", "--periods", "5,5"], "smaller than the number of frames"),
        (["--periods", "5,5"], "smaller than the number of frames"),  # periods: mixed radix
        (["--code", "residue", "--periods", "5,5"], "pairwise distinct"),
        (["--preset", "fancy"], "encoder_preset"),
        (["--rho", "1.5"], "rho"),
        (["--trainer", "forest"], "trainer"),
    ],
)
def test_bad_parameters_exit_non_zero_with_a_message(
    files: dict[str, Path], args: list[str], needle: str
) -> None:
    res = run("train", files["ref"], "--out", files["root"] / "never", *args)
    assert res.returncode != 0
    assert needle in res.stderr
    assert "Traceback" not in res.stderr
    assert not (files["root"] / "never").exists()


def test_a_csv_is_named_as_such_not_as_pickled_objects(files: dict[str, Path]) -> None:
    csv = files["root"] / "ref.csv"
    np.savetxt(csv, np.load(files["ref"])[:20], delimiter=",")
    res = run("train", csv, "--out", files["root"] / "never-csv", "--trainer", "ridge")
    assert res.returncode == 2, res.stderr
    assert "is not a .npy file" in res.stderr and "CSV" in res.stderr
    assert "pickled" not in res.stderr and "Traceback" not in res.stderr


def test_pickled_input_is_refused(files: dict[str, Path]) -> None:
    evil = files["root"] / "evil.npy"
    np.save(evil, np.array([object()], dtype=object), allow_pickle=True)
    res = run("train", evil, "--out", files["root"] / "never2")
    assert res.returncode == 2
    assert "pickled" in res.stderr and "Traceback" not in res.stderr
    assert "[unsafe_or_malformed_file]" in res.stderr  # the error code is printed, not eaten

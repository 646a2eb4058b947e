"""What ``gridplace`` says on a new user's first mistakes, as separate processes whose output
is a pipe (SYNTHETIC routes and images): exit codes, the preset a training run starts from,
storage beside exact NN's, and messages that read as sentences."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from service.encoding import ModelParams
from service.encoding.synthetic import smooth_route

CLI = [sys.executable, "-m", "service.cli"]
ENV = {k: v for k, v in os.environ.items() if k not in ("COLUMNS", "LINES")}


def run(*args: str | Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run([*CLI, *map(str, args)], capture_output=True, text=True, timeout=300,
                          env=ENV, check=False)  # fmt: skip


def one_line(text: str) -> str:
    return " ".join(text.split())


@pytest.fixture(scope="module")
def root(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("cli-messages")
    route = smooth_route(200, 48, seed=4)  # SYNTHETIC
    np.save(root / "ref.npy", route.reference)
    np.save(root / "query.npy", route.query)
    np.save(root / "narrow.npy", route.query[:, :40])
    np.save(root / "one.npy", route.query[:1])
    bad = route.query[:3].copy()
    bad[1, 2] = np.nan
    np.save(root / "nan.npy", bad)
    assert run("train", root / "ref.npy", "--out", root / "model").returncode == 0
    return root


def test_a_negative_tolerance_is_bad_input(root: Path) -> None:
    out = run("evaluate", root / "model", root / "query.npy", "--tolerance", "-1")
    assert out.returncode == 2 and "--tolerance" in out.stderr
    assert "precision@-1" not in out.stdout


def test_a_folder_of_images_names_gridplace_extract(root: Path) -> None:
    frames = root / "frames"
    frames.mkdir()
    for i in range(3):
        Image.fromarray(np.full((8, 8), 40 * i, np.uint8)).save(frames / f"f{i}.png")
    out = run("train", frames, "--out", root / "never")
    assert out.returncode == 2
    text = one_line(out.stderr)
    assert "is a folder of 3 images" in text and f"gridplace extract {frames}" in text
    assert "no such file" not in text and not (root / "never").exists()


def test_messages_read_as_sentences(root: Path) -> None:
    narrow = run("evaluate", root / "model", root / "narrow.npy")
    assert narrow.returncode == 2
    assert "narrow.npy: 40 columns, but the model expects 48" in one_line(narrow.stderr)
    nan = run("evaluate", root / "model", root / "nan.npy")
    assert nan.returncode == 2
    assert "nan.npy: NaN or infinite values (first at row 1, column 2)" in one_line(nan.stderr)
    single = run("evaluate", root / "model", root / "one.npy", "--no-adapt")
    assert single.returncode == 0, single.stderr
    assert "on 1 query;" in one_line(single.stdout) and "1 queries" not in single.stdout


def test_evaluate_states_storage_beside_exact_nn_and_the_paper_formula_only_for_its_code(
    root: Path,
) -> None:
    text = one_line(run("evaluate", root / "model", root / "query.npy", "--tolerance", "5").stdout)
    n, d = 200, 48
    assert f"exact NN on these {n} frames: {n * d:,} B as uint8 rows" in text
    assert "paper's formula" not in text  # the default stores prototypes, not the paper's code
    result = json.loads(run("evaluate", root / "model", root / "query.npy", "--json").stdout)
    assert isinstance(result["paper_bytes"], int) and result["exact_nn_uint8_bytes"] == n * d
    assert run("train", root / "ref.npy", "--out", root / "paper-code", "--trainer", "ridge",
               "--patterns", "2").returncode == 0  # fmt: skip
    paper = one_line(run("evaluate", root / "paper-code", root / "query.npy").stdout)
    assert "the paper's formula 8(d'+1)·Στ + k·d/8 (float64 weights) gives" in paper


@pytest.mark.parametrize(
    "args,preset,fields",
    [
        ([], "robust", {"trainer": "prototype", "n_components": 256}),
        (["--patterns", "2", "--rho", "0.5"], "paper",
         {"trainer": "logreg", "code": "mixed_radix", "n_components": None}),
        (["--trainer", "ridge", "--chunks", "2"], "paper",
         {"trainer": "ridge", "code": "mixed_radix", "n_components": None}),
        (["--components", "32"], "robust", {"trainer": "prototype", "n_components": 32}),
        (["--preset", "robust", "--patterns", "2"], "robust",
         {"trainer": "prototype", "n_patterns": 2, "n_components": 256}),
    ],
)  # fmt: skip
def test_train_says_and_records_the_preset_options_start_from(
    root: Path, tmp_path: Path, args: list[str], preset: str, fields: dict[str, object]
) -> None:
    out = run("train", root / "ref.npy", "--out", tmp_path / "m", *args)
    assert out.returncode == 0, out.stderr
    text = one_line(out.stdout)
    assert f"preset={preset}" in text
    assert ("the paper's code:" in text) == (preset == "paper" and "--preset" not in args)
    manifest = json.loads((tmp_path / "m" / "manifest.json").read_text())
    assert manifest["extra"]["encoder_preset"] == preset
    params = manifest["params"]
    for key, want in fields.items():
        assert params[key] == want, key
    # the same rule as the library's ModelParams
    given = dict(zip(args[::2], args[1::2], strict=True))
    names = {"--patterns": "n_patterns", "--rho": "rho", "--trainer": "trainer",
             "--chunks": "n_chunks", "--components": "n_components", "--preset": "encoder_preset"}
    kwargs = {names[k]: (v if k in ("--trainer", "--preset") else float(v) if "." in v else int(v))
              for k, v in given.items()}  # fmt: skip
    assert ModelParams(**kwargs).encoder_preset == preset  # type: ignore[arg-type]


def _frames(folder: Path, n: int) -> None:
    folder.mkdir()
    rng = np.random.default_rng(0)
    for i in range(n):
        Image.fromarray(rng.integers(0, 255, (24, 32), dtype=np.uint8)).save(folder / f"f{i:04d}.png")


def test_extract_refuses_an_existing_out_unless_overwrite(tmp_path: Path) -> None:
    _frames(tmp_path / "frames", 3)
    out = tmp_path / "q.npy"
    np.save(out, np.zeros(1))
    args = ["extract", tmp_path / "frames", "--out", out, "--extractor", "patchnorm",
            "--width", "32", "--height", "24", "--patch", "8"]  # fmt: skip
    refused = run(*args)
    assert refused.returncode == 2 and "--overwrite" in refused.stderr
    assert np.load(out).shape == (1,)  # untouched
    replaced = run(*args, "--overwrite")
    assert replaced.returncode == 0, replaced.stderr
    assert np.load(out).shape == (3, 32 * 24) and "3 frames" in replaced.stdout


def test_ctrl_c_during_extract_says_how_to_resume(tmp_path: Path) -> None:
    _frames(tmp_path / "frames", 400)
    out = tmp_path / "q.npy"
    # HOG on frames enlarged to 1024×768: slow enough to be interrupted mid-way
    args = ["extract", tmp_path / "frames", "--out", out, "--extractor", "hog",
            "--width", "1024", "--height", "768"]  # fmt: skip
    proc = subprocess.Popen([*CLI, *map(str, args)], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env=ENV)  # fmt: skip
    try:
        manifest = tmp_path / ".q.npy.partial" / "manifest.json"
        deadline = time.monotonic() + 120
        while not manifest.exists() and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.05)
        time.sleep(0.5)
        assert proc.poll() is None, "the extraction ended before it could be interrupted"
        proc.send_signal(signal.SIGINT)
        _, stderr = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 130
    assert "interrupted; run the same command again to resume" in one_line(stderr)
    assert "Traceback" not in stderr and not out.exists()


def test_lines_into_a_pipe_are_not_wrapped(root: Path, tmp_path: Path) -> None:
    out = tmp_path / ("a-rather-long-directory-name-" * 3) / "model_default_given"
    res = run("train", root / "ref.npy", "--out", out)
    assert res.returncode == 0, res.stderr
    (line,) = [ln for ln in res.stdout.splitlines() if ln.startswith("saved ")]
    assert str(out) in line and "exact NN on these 200 frames" in line  # one line, path whole

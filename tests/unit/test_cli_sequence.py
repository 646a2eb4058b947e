"""``gridplace evaluate|localize --sequence`` on .npy files (SYNTHETIC): one run as a user runs
it (a subprocess), the other cases through typer's runner in-process."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from service.cli import app
from service.encoding import PhaseEncoder, load_model, save_model
from service.encoding.adaptation import AdaptationConfig, adapt_drive
from service.encoding.sequence import SequenceConfig, sequence_localize
from service.encoding.synthetic import smooth_route


def invoke(*args: str | Path) -> tuple[int, str, str]:
    res = CliRunner().invoke(app, [str(a) for a in args])
    return res.exit_code, res.stdout, res.stderr


@pytest.fixture(scope="module")
def files(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("cli-seq")
    route = smooth_route(300, 32, query_noise=1.0, seed=13)  # SYNTHETIC, noisy queries
    np.save(root / "ref.npy", route.reference)
    np.save(root / "query.npy", route.query)
    np.save(root / "gt.npy", np.arange(300))
    save_model(PhaseEncoder(trainer="ridge").fit(route.reference), root / "model")
    return {
        "root": root,
        "model": root / "model",
        "query": root / "query.npy",
        "gt": root / "gt.npy",
    }


def test_evaluate_sequence_adds_the_filter_precision(files: dict[str, Path]) -> None:
    code, stdout, _ = invoke(
        "evaluate", files["model"], files["query"], "--tolerance", "5", "--json"
    )
    assert code == 0
    args = ["evaluate", files["model"], files["query"], "--tolerance", "5", "--json", "--sequence",
            "--ground-truth", files["gt"]]  # fmt: skip
    res = subprocess.run(  # as a user runs it
        [sys.executable, "-m", "service.cli", *map(str, args)],
        capture_output=True, text=True, timeout=300, check=False,
    )  # fmt: skip
    assert res.returncode == 0, res.stderr
    base, out = json.loads(stdout), json.loads(res.stdout)
    assert (
        set(base) <= set(out) and out["precision"] == base["precision"]
    )  # today's keys, same values
    assert set(out["sequence_precision_at"]) == set(out["precision_at"])
    assert out["sequence_precision"] == out["sequence_precision_at"]["5"]
    assert out["sequence_precision"] > out["precision"] + 0.1, (
        out["precision"],
        out["sequence_precision"],
    )
    assert out["sequence"]["filter"] == SequenceConfig().model_dump()
    assert out["sequence"]["seconds_per_frame"] > 0 and 0 <= out["sequence"]["mean_confidence"] <= 1
    code, stdout, _ = invoke(
        "evaluate", files["model"], files["query"], "--tolerance", "5", "--sequence"
    )
    assert code == 0 and "sequence precision@5" in stdout


def test_localize_sequence_writes_the_filtered_indices(files: dict[str, Path]) -> None:
    pred = files["root"] / "seq.npy"
    code, _, stderr = invoke(
        "localize",
        files["model"],
        files["query"],
        "--sequence",
        "--out",
        pred,
        "--filter",
        "emission_scale=0.2",
        "--filter",
        "reverse=true",
    )
    assert code == 0, stderr
    config = SequenceConfig(emission_scale=0.2, reverse=True)
    model = load_model(files["model"])
    drive = adapt_drive(model, np.load(files["query"]))  # adapted by default
    np.testing.assert_array_equal(np.load(pred), sequence_localize(model, drive, config).index)
    code, _, stderr = invoke("localize", files["model"], files["query"], "--no-adapt", "--out", pred)
    assert code == 0, stderr
    np.testing.assert_array_equal(np.load(pred), model.localize(np.load(files["query"])).index)


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (["--sequence", "--filter", "emission_scale=-1"], "emission_scale"),
        (["--sequence", "--filter", "nonsense"], "KEY=VALUE"),
        (["--sequence", "--filter", "speed=2"], "speed"),
        (["--filter", "reverse=true"], "needs --sequence"),
    ],
)
def test_bad_filter_options_exit_2_naming_the_problem(
    files: dict[str, Path], args: list[str], needle: str
) -> None:
    for command in ("evaluate", "localize"):
        code, stdout, stderr = invoke(command, files["model"], files["query"], *args)
        assert code == 2, (command, stdout, stderr)
        assert "invalid_parameter" in stderr and needle in stderr


def test_odometry_files_reach_the_filter(files: dict[str, Path]) -> None:
    Q = np.load(files["query"])
    n = Q.shape[0]
    text = files["root"] / "odo.txt"
    text.write_text("\n".join("" if t == 3 else "1.0" for t in range(n)) + "\n")
    npy = files["root"] / "odo.npy"
    np.save(npy, np.ones(n))
    pred = files["root"] / "odo-pred.npy"
    model = load_model(files["model"])
    steps: list[float | None] = [None if t == 3 else 1.0 for t in range(n)]
    for path, odometry in ((text, steps), (npy, np.ones(n))):
        code, _, stderr = invoke("localize", files["model"], files["query"], "--sequence",
                                 "--no-adapt", "--odometry", path, "--out", pred)  # fmt: skip
        assert code == 0, stderr
        want = sequence_localize(model, Q, SequenceConfig(), odometry=odometry).index
        np.testing.assert_array_equal(np.load(pred), want)
    code, stdout, stderr = invoke("evaluate", files["model"], files["query"], "--sequence",
                                  "--odometry", npy, "--json")  # fmt: skip
    assert code == 0 and json.loads(stdout)["sequence_precision"] >= 0, stderr


@pytest.mark.parametrize(
    ("values", "needle"),
    [("nan", "NaN"), ("short", "odometry values"), ("word", "not a number"), ("big", "exceeds")],
)
def test_bad_odometry_exits_2_naming_the_problem(
    files: dict[str, Path], values: str, needle: str
) -> None:
    n = np.load(files["query"]).shape[0]
    path = files["root"] / f"bad-{values}.npy"
    if values == "nan":
        np.save(path, np.r_[np.ones(n - 1), np.nan])
    elif values == "short":
        np.save(path, np.ones(n - 1))
    elif values == "big":
        np.save(path, np.r_[np.ones(n - 1), 1e9])
    else:
        path = path.with_suffix(".txt")
        path.write_text("1\nfast\n")
    for command in ("evaluate", "localize"):
        code, stdout, stderr = invoke(command, files["model"], files["query"], "--sequence",
                                      "--odometry", path)  # fmt: skip
        assert code == 2 and needle in stderr, (command, stdout, stderr)
    code, _, stderr = invoke("localize", files["model"], files["query"], "--odometry", path)
    assert code == 2 and "--odometry needs --sequence" in stderr


def test_bench_sequence_smoke(tmp_path: Path) -> None:
    """A tiny run of ``gridplace bench sequence`` (cost only) writes its JSON."""
    out = tmp_path / "bench.json"
    code, stdout, stderr = invoke(
        "bench", "sequence", "--sizes", "300", "--repeats", "3", "--no-nordland", "--out", out
    )
    assert code == 0, stderr
    cost = json.loads(out.read_text())["filter_cost"]["300"]
    assert cost["hmm"]["cpu_us"] > 0 and cost["seqslam"]["wall_us"] > 0 and cost["hmm_speeds"] == SequenceConfig().n_states
    assert "speed-up" in stdout


def test_bench_tuning_picks_the_best_candidate_on_the_drives() -> None:
    from service.bench.sequence_bench import tune, validation_drives

    drives = validation_drives(300)
    assert set(drives) == {"speed_1", "speed_0.7", "speed_1.5", "varying", "kidnap", "stops"}
    for pos in drives.values():
        assert pos.min() >= 0 and pos.max() < 300 and pos.size > 100
    route = smooth_route(300, 24, query_noise=0.8, seed=2)  # SYNTHETIC
    S = PhaseEncoder(trainer="ridge").fit(route.reference).frame_log_scores(route.query)
    result = tune({"gridplace": S}, "tiny")
    means = {r["config"]["method"]: r["mean"] for r in result["candidates"]}
    assert result["best"]["method"] == max(means, key=means.get)  # type: ignore[arg-type]
    assert set(result["drives"]) == set(drives) and result["split"] == "A"


def test_evaluate_adapts_the_queries_unless_told_not_to(files: dict[str, Path]) -> None:
    model = load_model(files["model"])
    Q = np.load(files["query"])
    code, stdout, _ = invoke("evaluate", files["model"], files["query"], "--tolerance", "2", "--json")
    on = json.loads(stdout)
    assert code == 0 and on["adaptation"] == AdaptationConfig().model_dump()
    truth = np.arange(Q.shape[0])
    adapted = model.localize(adapt_drive(model, Q)).index
    assert on["precision"] == pytest.approx(np.mean(np.abs(adapted - truth) <= 2))
    code, stdout, _ = invoke("evaluate", files["model"], files["query"], "--tolerance", "2", "--json",
                             "--no-adapt")  # fmt: skip
    off = json.loads(stdout)
    assert code == 0 and off["adaptation"] is None
    assert off["precision"] == pytest.approx(np.mean(np.abs(model.localize(Q).index - truth) <= 2))
    code, stdout, _ = invoke("evaluate", files["model"], files["query"])
    assert code == 0 and "appearance adaptation on" in stdout


def test_a_model_without_route_statistics_is_evaluated_unadapted(files: dict[str, Path]) -> None:
    route = smooth_route(120, 16, seed=3)  # SYNTHETIC
    bare = files["root"] / "bare"
    np.save(files["root"] / "q16.npy", route.query)
    save_model(PhaseEncoder(trainer="ridge", normalize=False).fit(route.reference), bare)
    code, stdout, _ = invoke("evaluate", bare, files["root"] / "q16.npy", "--json")
    assert code == 0 and json.loads(stdout)["adaptation"] is None
    code, _, stderr = invoke("evaluate", bare, files["root"] / "q16.npy", "--adapt")
    assert code == 2 and "statistics" in stderr


def test_odometry_in_metres_is_divided_by_the_spacing(files: dict[str, Path]) -> None:
    Q = np.load(files["query"])
    n = Q.shape[0]
    metres = files["root"] / "odo-m.npy"
    np.save(metres, np.full(n, 2.5))
    pred = files["root"] / "odo-m-pred.npy"
    code, _, stderr = invoke("localize", files["model"], files["query"], "--sequence", "--no-adapt",
                             "--odometry", metres, "--odometry-spacing", "2.5", "--out", pred)  # fmt: skip
    assert code == 0, stderr
    model = load_model(files["model"])
    want = sequence_localize(model, Q, SequenceConfig(), odometry=np.ones(n)).index
    np.testing.assert_array_equal(np.load(pred), want)
    for spacing, needle in (("-1", "positive"), ("0", "positive")):
        code, _, stderr = invoke("localize", files["model"], files["query"], "--sequence",
                                 "--odometry", metres, "--odometry-spacing", spacing)  # fmt: skip
        assert code == 2 and needle in stderr, stderr
    code, _, stderr = invoke("localize", files["model"], files["query"], "--sequence",
                             "--odometry-spacing", "2")  # fmt: skip
    assert code == 2 and "needs --odometry" in stderr

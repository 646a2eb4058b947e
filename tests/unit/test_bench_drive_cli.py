"""``gridplace bench drive`` end to end on a small SYNTHETIC route, in seconds."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from typer.testing import CliRunner

from service.bench import drive_bench
from service.bench import drive_protocols as dp
from service.cli import app
from service.encoding.sequence import SequenceConfig, SequenceTrack, filter_sequence

SMALL = ["--synthetic", "400", "--drives", "12", "--short-length", "40", "--speed-drives", "1",
         "--speed-frames", "150", "--traffic-drives", "2", "--kidnap-drives", "4", "--kidnap-before", "40",
         "--kidnap-after", "60", "--min-jump", "80", "--odometry-noise", "0.1"]  # fmt: skip


def invoke(*args: str | Path) -> tuple[int, str, str]:
    res = CliRunner().invoke(app, ["bench", "drive", *(str(a) for a in args)])
    return res.exit_code, res.stdout, res.stderr


def test_the_bench_drives_every_method_through_the_filter(tmp_path: Path) -> None:
    out, md = tmp_path / "drive.json", tmp_path / "drive.md"
    code, stdout, stderr = invoke(*SMALL, "--methods", "exact-nn,robust,residue-r0.1",
                                  "--tune", "shared", "--grid", "emission_scale=0.05,0.2",
                                  "--grid", "stop_probability=0", "--grid", "relocalization=1e-4",
                                  "--grid", "speed_change=0.01", "--out", out, "--markdown", md)  # fmt: skip
    assert code == 0, stderr
    r = json.loads(out.read_text())
    assert r["data"]["synthetic"] and "SYNTHETIC" in r["data"]["label"]
    assert set(r["methods"]) == {"exact-nn", "robust", "residue-r0.1"}
    assert set(r["drives"]["B"]) == {"whole", "short", "speed", "traffic", "kidnap", "reverse"}
    for name, m in r["methods"].items():
        assert m["bytes"] > 0 and m["components"], name
        assert set(m["results"]) == {"default", "tuned"}
        for split in ("B", "all"):
            f = m["results"]["default"][split]["none"]
            assert len(f["short"]["curve"]) == 40
            assert 0.0 <= f["speed"]["precision"] <= 1.0
            assert set(f["speed"]["by_profile"]) == set(dp.SPEED_PROFILES)
            assert f["traffic"]["drives"] == 2 and 0.0 <= f["traffic"]["precision"] <= 1.0
            assert f["kidnap"]["recovery"]["drives"] == 4
    assert len(r["methods"]["residue-r0.1"]["periods"]) == 2  # the fitted code is recorded
    assert r["methods"]["exact-nn"]["periods"] is None
    nn = r["methods"]["exact-nn"]["results"]["default"]["B"]["none"]
    assert nn["whole"]["precision"] > 0.9 and nn["short"]["l90"] is not None
    assert nn["reverse"]["precision_reverse_filter"] > 0.9  # a reverse drive needs reverse=true
    odo = r["methods"]["exact-nn"]["results"]["default"]["B"]["odometry_0.1"]
    if r["odometry"]["available"]:
        assert 0.0 <= odo["speed"]["precision"] <= 1.0
    else:
        assert odo == {"available": False}
    # the tuned configuration is the shared best on A, printed and used
    tuning = r["tuning"]
    assert tuning["split"] == "A" and len(tuning["candidates"]) == 2
    best = max(tuning["candidates"], key=lambda c: c["mean"])["config"]["emission_scale"]
    assert all(c["emission_scale"] == best for c in tuning["chosen"].values())
    assert "tuned on A for exact-nn" in stdout and "L90" in stdout
    assert "| `robust` |" in md.read_text()
    assert out.with_suffix(".png").stat().st_size > 1000
    # the tables again from the JSON, without running anything
    again = tmp_path / "again.md"
    code, stdout, stderr = invoke("--report", out, "--markdown", again, "--figure",
                                  tmp_path / "again.png")  # fmt: skip
    assert code == 0, stderr
    assert again.read_text() == md.read_text() and "code bytes" in stdout


def test_a_run_of_one_protocol_writes_its_tables_and_figure(tmp_path: Path) -> None:
    """Without whole, variable-speed or short drives the figure says so instead of failing
    on an empty log axis."""
    out = tmp_path / "traffic.json"
    code, stdout, stderr = invoke(*SMALL, "--methods", "exact-nn", "--protocols", "traffic",
                                  "--out", out)  # fmt: skip
    assert code == 0, stderr
    assert set(json.loads(out.read_text())["drives"]["B"]) == {"traffic"}
    assert out.with_suffix(".png").stat().st_size > 1000 and "traffic" in stdout


@pytest.mark.parametrize(("args", "needle"), [
    (["--methods", "nope"], "unknown method"),
    (["--protocols", "whole,loop"], "unknown protocol"),
    (["--odometry-noise", "0.1,x"], "not numbers"),
    (["--tune", "always"], "--tune"),
    (["--grid", "alpha=1"], "--grid"),
    (["--filter", "emission_scale=-1"], "emission_scale"),
    (["--reference", "r.npy", "--query", "q.npy"], "give one of"),
])  # fmt: skip
def test_bad_options_exit_2_naming_the_problem(tmp_path: Path, args: list[str],
                                               needle: str) -> None:  # fmt: skip
    code, stdout, stderr = invoke(*SMALL, *args, "--out", tmp_path / "x.json")
    assert code == 2, (stdout, stderr)
    assert needle in stderr


def test_a_reference_needs_its_query(tmp_path: Path) -> None:
    code, _, stderr = invoke("--reference", tmp_path / "r.npy", "--out", tmp_path / "x.json")
    assert code == 2 and "--reference and --query go together" in stderr


def test_odometry_reaches_the_filter_when_it_takes_some(monkeypatch: pytest.MonkeyPatch) -> None:
    """With a filter that takes ``odometry=``, every drive's noisy odometry is passed, one
    value per frame; without, the rows say unavailable (nothing is made up)."""
    seen: list[np.ndarray] = []

    def with_odometry(scores: np.ndarray, config: SequenceConfig | None = None,
                      odometry: np.ndarray | None = None) -> SequenceTrack:  # fmt: skip
        if odometry is not None:
            assert odometry.shape == (scores.shape[0],)
            seen.append(odometry)
        return filter_sequence(scores, config)

    S = np.random.default_rng(0).normal(size=(300, 300)).astype(np.float32)
    drives = {s: drive_bench.make_drives(lo, hi, np.arange(300), drive_bench.DriveSettings(
        protocols=("whole", "speed"), speed_drives=1, speed_frames=100), 0)
        for s, (lo, hi) in drive_bench.splits(300).items()}  # fmt: skip
    settings = drive_bench.DriveSettings(odometry_noise=(0.1,))

    def without_odometry(scores: np.ndarray, config: SequenceConfig | None = None) -> SequenceTrack:
        return filter_sequence(scores, config)

    monkeypatch.setattr(drive_bench, "filter_sequence", without_odometry)
    plain = drive_bench.evaluate_all(S, drives, SequenceConfig(), settings)
    assert plain["B"]["odometry_0.1"] == {"available": False}
    monkeypatch.setattr(drive_bench, "filter_sequence", with_odometry)
    got: dict[str, Any] = drive_bench.evaluate_all(S, drives, SequenceConfig(), settings)
    assert "speed" in got["B"]["odometry_0.1"] and len(seen) == 8  # 2 splits × (1 whole + 3 speed)
    whole_b = drives["B"]["whole"][0]
    assert any(o.size == len(whole_b) and abs(o.mean() - 1.0) < 0.05 for o in seen)


def test_a_folder_of_images_goes_through_an_image_extractor(tmp_path: Path) -> None:
    from PIL import Image

    from service.encoding.synthetic import smooth_route

    route = smooth_route(120, 32 * 64, smoothness=3.0, query_noise=0.3, seed=1)  # SYNTHETIC
    for side, rows in (("reference", route.reference), ("query", route.query)):
        (tmp_path / "imgs" / side).mkdir(parents=True)
        pixels = np.clip(128 + 40 * rows, 0, 255).astype(np.uint8).reshape(-1, 32, 64)
        for i, img in enumerate(pixels):
            Image.fromarray(img).save(tmp_path / "imgs" / side / f"{i:04d}.png")
    out = tmp_path / "res" / "drive.json"
    code, _, stderr = invoke(tmp_path / "imgs", "--extractor", "patchnorm", "--methods",
                             "exact-nn", "--protocols", "whole,short", "--drives", "5",
                             "--short-length", "20", "--odometry-noise", "", "--out", out)  # fmt: skip
    assert code == 0, stderr
    r = json.loads(out.read_text())
    assert r["data"]["name"] == "imgs-patchnorm" and r["n_frames"] == 120
    assert (tmp_path / "res" / "extracted" / "imgs-patchnorm-query.npy").is_file()
    assert r["methods"]["exact-nn"]["results"]["default"]["all"]["none"]["whole"]["precision"] > 0.5

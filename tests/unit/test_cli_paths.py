"""Where a benchmark writes: a missing folder is made, and a ``--work-dir`` or ``--out`` it
cannot write is refused before any work, as exit 2 with the option named (no traceback)."""

from __future__ import annotations

from pathlib import Path

import pytest
from typer.testing import CliRunner

from service.cli import app
from service.cli.paths import output_file, writable_dir


@pytest.mark.parametrize("command", ["drive-scaling", "scale", "growth"])
def test_a_bench_refuses_a_work_dir_or_out_it_cannot_write(tmp_path: Path, command: str) -> None:
    blocker = tmp_path / "a-file"
    blocker.write_text("")
    for option, value, says in (("--work-dir", blocker, "not a folder"),
                                ("--work-dir", blocker / "below", "cannot be made"),
                                ("--out", tmp_path, "a folder, not a file")):  # fmt: skip
        got = CliRunner().invoke(app, ["bench", command, "--sizes", "1000", option, str(value)])
        assert got.exit_code == 2, got.output
        assert says in " ".join(got.output.split()) and option in got.output
        assert got.exception is None or isinstance(got.exception, SystemExit)


def test_missing_folders_are_made(tmp_path: Path) -> None:
    assert writable_dir(tmp_path / "a" / "b", "--work-dir") == tmp_path / "a" / "b"
    assert (tmp_path / "a" / "b").is_dir() and writable_dir(None, "--work-dir") is None
    out = output_file(tmp_path / "c" / "d.json", "--out")
    assert out.parent.is_dir() and not out.exists()


@pytest.mark.parametrize("option", ["--out", "--markdown"])
def test_bench_drive_refuses_a_folder_as_its_report(tmp_path: Path, option: str) -> None:
    got = CliRunner().invoke(app, ["bench", "drive", "--synthetic", "2000", option, str(tmp_path)])
    assert got.exit_code == 2, got.output
    assert "a folder, not a file" in " ".join(got.output.split()) and option in got.output


@pytest.mark.parametrize("command", [
    ["train"], ["workers"], ["serve"], ["grpc"], ["sequence"], ["quality"], ["public-rss"],
    ["scale-real", "--reference", "r.npy", "--query", "q.npy"],
    ["append", "--ref", "r.npy", "--qry", "q.npy"],
    ["conditions", "--ref", "r.npy", "--qry", "q.npy"],
])  # fmt: skip
def test_every_bench_refuses_a_folder_as_its_json_before_any_work(tmp_path: Path,
                                                                  command: list[str]) -> None:  # fmt: skip
    got = CliRunner().invoke(app, ["bench", *command, "--out", str(tmp_path)])
    assert got.exit_code == 2, got.output
    assert "a folder, not a file" in " ".join(got.output.split()) and "--out" in got.output
    assert got.exception is None or isinstance(got.exception, SystemExit)


def test_bench_paper_refuses_a_file_as_its_output_folder(tmp_path: Path) -> None:
    blocker = tmp_path / "a-file"
    blocker.write_text("")
    got = CliRunner().invoke(app, ["bench", "paper", "--out", str(blocker)])
    assert got.exit_code == 2, got.output
    assert "not a folder" in " ".join(got.output.split()) and "--out" in got.output
    got = CliRunner().invoke(app, ["bench", "paper", "--out", str(tmp_path / "o"),
                                   "--markdown", str(tmp_path)])  # fmt: skip
    assert got.exit_code == 2 and "a folder, not a file" in " ".join(got.output.split())

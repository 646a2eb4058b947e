"""``gridplace extract`` and ``gridplace serve --help``."""

from __future__ import annotations

import json

import numpy as np
from api_helpers import png_bytes
from typer.testing import CliRunner

from service.cli import app
from service.imaging import decode_image, make_extractor
from service.settings import Settings

runner = CliRunner()


def test_extract_orders_frames_by_file_name(tmp_path) -> None:
    frames = tmp_path / "frames"
    frames.mkdir()
    for i in (3, 1, 2, 10):
        (frames / f"img-{i:03d}.png").write_bytes(png_bytes(i))
    (frames / "notes.txt").write_text("not a frame")
    out = tmp_path / "ref.npy"
    r = runner.invoke(app, ["extract", str(frames), "--out", str(out), "--extractor", "patchnorm",
                            "--width", "32", "--height", "16", "--patch", "8"])  # fmt: skip
    assert r.exit_code == 0, r.output
    X = np.load(out, allow_pickle=False)
    config = json.loads((tmp_path / "ref.npy.extractor.json").read_text())
    assert config == {"kind": "patchnorm", "width": 32, "height": 16, "patch": 8}
    want = make_extractor(config).extract([decode_image(png_bytes(i)) for i in (1, 2, 3, 10)])
    np.testing.assert_array_equal(X, want)


def test_extract_errors_are_clear(tmp_path) -> None:
    r = runner.invoke(app, ["extract", str(tmp_path), "--out", str(tmp_path / "x.npy")])
    assert r.exit_code == 2 and "no image files" in r.output
    (tmp_path / "bad.png").write_bytes(b"not a png")
    r = runner.invoke(app, ["extract", str(tmp_path), "--out", str(tmp_path / "x.npy")])
    assert r.exit_code == 2 and "not a decodable image" in r.output
    r = runner.invoke(app, ["extract", str(tmp_path), "--out", "x.npy", "--extractor", "patchnorm",
                            "--width", "60"])  # fmt: skip
    assert r.exit_code == 2 and "multiples of patch" in r.output


def test_serve_help_documents_every_setting() -> None:
    r = runner.invoke(app, ["serve", "--help"], terminal_width=200)
    assert r.exit_code == 0
    for name in Settings.model_fields:
        assert f"GRIDPLACE_{name.upper()}" in r.output, name

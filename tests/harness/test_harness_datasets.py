"""Dataset loading: images folders, .npy matrices, preprocessing, ground truth, synthetic."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from service.bench.data import shared_data_dir
from service.errors import InvalidInputError, InvalidParameterError
from service.harness.datasets import Dataset, load_dataset, synthetic_dataset

H, W = 32, 64


def _frames(n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return rng.integers(0, 256, size=(n, H, W), dtype=np.uint8)


def _write_images(folder: Path, frames: np.ndarray) -> None:
    folder.mkdir(parents=True)
    order = np.random.default_rng(1).permutation(len(frames))  # write out of order
    for i in order:
        Image.fromarray(frames[i]).save(folder / f"images-{(i + 1) * 10:05d}.png")


def test_images_folders_are_read_in_file_name_order_and_patch_normalised(tmp_path: Path) -> None:
    ref, qry = _frames(12, 0), _frames(12, 1)
    _write_images(tmp_path / "reference", ref)
    _write_images(tmp_path / "query", qry)
    ds = load_dataset(tmp_path, patch=16)
    assert ds.reference.shape == (12, H * W) and ds.reference.dtype == np.float32
    from service.encoding.features import patch_normalize

    np.testing.assert_allclose(ds.reference, patch_normalize(ref, 16), atol=1e-5)
    np.testing.assert_allclose(ds.query, patch_normalize(qry, 16), atol=1e-5)
    assert ds.preprocessing["mode"] == "patch" and ds.preprocessing["patch"] == 16
    assert ds.preprocessing["image_shape"] == [H, W]
    assert ds.preprocessing["ground_truth"] == "identity"
    np.testing.assert_array_equal(ds.ground_truth, np.arange(12))
    assert not ds.synthetic and "patch-normalised" in ds.label


def test_npy_is_preferred_and_takes_its_image_shape_from_the_images(tmp_path: Path) -> None:
    ref, qry = _frames(6, 2), _frames(6, 3)
    _write_images(tmp_path / "reference", ref)
    _write_images(tmp_path / "query", qry)
    np.save(tmp_path / "reference.npy", ref.reshape(6, -1))
    np.save(tmp_path / "query.npy", qry.reshape(6, -1))
    ds = load_dataset(tmp_path)
    assert ds.preprocessing["reference_from"] == "reference.npy"
    assert ds.preprocessing["mode"] == "patch"
    assert ds.n_features == H * W


def test_float_descriptors_are_used_as_stored_and_ground_truth_is_applied(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    (tmp_path / "reference").mkdir()
    np.save(tmp_path / "reference" / "descriptors.npy", rng.normal(size=(20, 8)))
    np.save(tmp_path / "query.npy", rng.normal(size=(5, 8)).astype(np.float32))
    truth = np.array([3, 0, 19, 7, 7])
    np.save(tmp_path / "ground_truth.npy", truth)
    ds = load_dataset(tmp_path)
    assert ds.preprocessing["mode"] == "none"
    assert ds.preprocessing["ground_truth"] == "ground_truth.npy"
    np.testing.assert_array_equal(ds.ground_truth, truth)
    ref, q, gt = ds.segment(8)  # central frames 6..13: queries 3 and 4 (place 7)
    np.testing.assert_array_equal(ref, ds.reference[6:14])
    np.testing.assert_array_equal(gt, [1, 1])
    np.testing.assert_array_equal(q, ds.query[[3, 4]])
    with pytest.raises(InvalidParameterError):
        ds.segment(21)


def test_raw_pixel_npy_needs_an_image_shape(tmp_path: Path) -> None:
    frames = _frames(4, 5).reshape(4, -1)
    np.save(tmp_path / "reference.npy", frames)
    np.save(tmp_path / "query.npy", frames)
    with pytest.raises(InvalidParameterError, match="image shape"):
        load_dataset(tmp_path)
    assert load_dataset(tmp_path, image_shape=(H, W)).n_features == H * W
    assert load_dataset(tmp_path, preprocess="none").preprocessing["mode"] == "none"


@pytest.mark.parametrize(
    ("truth", "message"),
    [
        (np.array([0, 1]), "one index per query"),
        (np.array([0, 1, 99]), "must lie in"),
        (np.array([0.0, 1.0, 2.0]), "integers"),
    ],
)
def test_bad_ground_truth_is_named(tmp_path: Path, truth: np.ndarray, message: str) -> None:
    np.save(tmp_path / "reference.npy", np.ones((10, 4), dtype=np.float32))
    np.save(tmp_path / "query.npy", np.ones((3, 4), dtype=np.float32))
    np.save(tmp_path / "ground_truth.npy", truth)
    with pytest.raises(InvalidInputError, match=message):
        load_dataset(tmp_path)


def test_missing_traversal_and_unknown_mode_are_named(tmp_path: Path) -> None:
    np.save(tmp_path / "reference.npy", np.ones((10, 4), dtype=np.float32))
    with pytest.raises(InvalidInputError, match="query"):
        load_dataset(tmp_path)
    with pytest.raises(InvalidParameterError, match="preprocessing"):
        load_dataset(tmp_path, preprocess="sift")
    with pytest.raises(InvalidInputError, match="does not exist"):
        load_dataset(tmp_path / "nope")


def test_synthetic_dataset_says_it_is_synthetic() -> None:
    ds = synthetic_dataset(50, 16, seed=1)
    assert ds.synthetic and "SYNTHETIC" in ds.label and ds.describe()["synthetic"]
    assert ds.reference.shape == ds.query.shape == (50, 16)


@pytest.mark.skipif(shared_data_dir() is None, reason="real Nordland data not present")
def test_the_real_nordland_folder_loads_directly() -> None:
    root = shared_data_dir()
    assert root is not None
    ds = load_dataset(root / "nordland-64x32")
    assert ds.n_frames == 3576 and ds.n_features == 2048
    assert ds.preprocessing["mode"] == "patch" and ds.preprocessing["image_shape"] == [32, 64]
    assert ds.preprocessing["reference_from"] == "reference.npy"
    assert np.isfinite(ds.query[:100]).all()


def test_regional_component_makes_distant_parts_of_a_synthetic_route_differ() -> None:
    plain = synthetic_dataset(3000, 8, seed=4)
    regional = synthetic_dataset(3000, 8, region_length=300, seed=4)
    assert "regional component every 300 frames" in regional.label
    assert regional.preprocessing["region_length"] == 300

    def block_mean_spread(ds: Dataset) -> float:
        return float(ds.reference.reshape(10, 300, 8).mean(axis=1).std())

    assert block_mean_spread(regional) > 3 * block_mean_spread(plain)
    np.testing.assert_allclose(regional.query - regional.reference,
                               plain.query - plain.reference, atol=1e-5)  # fmt: skip

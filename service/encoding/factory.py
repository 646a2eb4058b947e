"""Training parameters as one validated object, and the model they describe.

The CLI, the API and the queue all describe a training run with :class:`ModelParams`; an
unchunked route (``n_chunks = 1``) gets a :class:`PhaseEncoder`, a longer one a
:class:`ChunkedPlaceEncoder`.
"""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from service.encoding.chunked import ChunkedPlaceEncoder
from service.encoding.encoder import PhaseEncoder
from service.encoding.presets import DEFAULT_PRESET, PresetName, base_preset, preset
from service.errors import InvalidParameterError

Period = Annotated[int, Field(ge=2, le=2**31 - 1)]

PAPER_TRAINER = "logreg"  # LIBLINEAR L2 logistic regression, C = 4, as in the paper's code
_DEFAULT = preset(DEFAULT_PRESET)


def default_trainer() -> str:
    """The trainer used when none is named (CLI, REST uploads, demo): the default preset's
    (:data:`service.encoding.presets.DEFAULT_PRESET`), the one place to change it.

    The paper's ``logreg`` (:data:`PAPER_TRAINER`) and the others stay available by name.
    """
    return _DEFAULT.trainer


class ModelParams(BaseModel):
    """Every training parameter; with none given, those of the default preset (``robust``).

    The encoder-defining fields come from one preset, :func:`~service.encoding.presets.base_preset`:
    the named ``encoder_preset``; else ``paper`` when an option only the paper's code uses is
    given (``n_patterns``, ``periods``, ``rho``, ``gamma``, ``C``, ``code="mixed_radix"``, a
    trainer other than ``prototype``); else the default. Fields given explicitly override the
    preset's, and ``encoder_preset`` records the preset used. Explicit ``periods`` without an
    explicit ``code`` are mixed-radix periods (product ≥ N); residue periods are named with
    ``code="residue"``. Another trainer than the preset's drops the preset's calibrated
    temperature (its own default applies)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    encoder_preset: PresetName | None = Field(
        None, description="the preset the encoder fields start from (paper | ridge | robust | "
        "residue); recorded after validation, see base_preset()",
    )
    n_patterns: int = Field(_DEFAULT.n_patterns, ge=1, le=16,
                            description="number of phase encoders k")  # fmt: skip
    periods: tuple[Period, ...] | None = Field(
        None, min_length=1, max_length=64, description="explicit periods τ1…τk"
    )
    rho: float = Field(_DEFAULT.rho, gt=0.0, le=1.0, description="fraction of columns per encoder")
    gamma: float | None = Field(
        None, ge=1.0, allow_inf_nan=False, description="L1 bound of pattern weights"
    )
    trainer: Literal["logreg", "svm", "ridge", "torch", "prototype"] = Field(
        _DEFAULT.trainer, description="see default_trainer()"
    )
    C: float = Field(_DEFAULT.C, gt=0.0, allow_inf_nan=False,
                     description="inverse regularisation strength")  # fmt: skip
    decode: Literal["joint", "argmax"] = "joint"
    beam_width: int = Field(64, ge=1, le=100_000)
    dtype: Literal["float64", "float32", "float16", "int8", "binary"] = _DEFAULT.dtype
    code: Literal["mixed_radix", "residue"] = Field(
        _DEFAULT.code, description="digit labels: mixed radix (the paper's) or i mod τ_j"
    )
    code_ratio: float = Field(_DEFAULT.code_ratio, gt=0.0, le=64.0, allow_inf_nan=False,
                              description="sum of automatic residue periods / N^code_exponent")  # fmt: skip
    code_exponent: float = Field(_DEFAULT.code_exponent, gt=0.0, le=1.0, allow_inf_nan=False,
                                 description="the code grows as N^code_exponent")  # fmt: skip
    n_components: int | None = Field(
        _DEFAULT.n_components, ge=1, le=65_536, description="PCA projection width (None: none)"
    )
    whiten_power: float = Field(_DEFAULT.whiten_power, ge=0.0, le=1.0,
                                description="PCA whitening power")  # fmt: skip
    temperature: float | None = Field(
        _DEFAULT.temperature, gt=0.0, allow_inf_nan=False,
        description="score temperature (None: the trainer's default)",
    )
    auto_width: bool = Field(
        True, description="projection width chosen from the route: at most n_components, at "
        "most 0.7 of the training rows, and the model within N·d bytes (exact NN on uint8 "
        "rows); false: n_components as given",
    )
    search: Literal["flat", "ivf", "auto"] = Field(
        "auto", description="how a route with one class per frame (the default preset) is "
        "searched: flat scans every frame (exact), ivf through an inverted file of its "
        "prototypes, auto the inverted file from 65,536 frames on (unchunked routes)",
    )
    n_chunks: int = Field(1, ge=1, le=100_000, description="1 = no chunking")
    chunk_rho: float | None = Field(None, gt=0.0, le=1.0)
    top_chunks: int = Field(2, ge=1, le=100_000)
    n_jobs: int = Field(
        1, ge=-1, description="parallel chunk processes, or one-vs-rest threads without chunks"
    )
    random_state: int | None = Field(0, ge=0, le=2**32 - 1, description="seed of the trainers")
    frame_spacing_m: float | None = Field(
        None, gt=0.0, le=10_000.0, allow_inf_nan=False,
        description="metres between consecutive reference frames (recorded with the version: "
        "odometry in metres is divided by it)",
    )  # fmt: skip

    @model_validator(mode="before")
    @classmethod
    def _apply_preset(cls, data: Any) -> Any:
        if not isinstance(data, dict):
            return data
        if data.get("periods") is not None and data.get("code") is None:
            data = {**data, "code": "mixed_radix"}
        name, _ = base_preset(data)
        try:
            base = preset(name)
        except KeyError:
            return data  # the Literal field reports the unknown name
        out = {**base.params(), **data, "encoder_preset": name}
        if out["trainer"] != base.trainer and data.get("temperature") is None:
            out["temperature"] = None  # the preset's T was calibrated for its own trainer
        return out

    @classmethod
    def parse(cls, **kwargs: object) -> ModelParams:
        """Like the constructor, but raises :class:`InvalidParameterError`."""
        try:
            return cls(**kwargs)  # type: ignore[arg-type]
        except ValidationError as exc:
            msgs = "; ".join(
                f"{'.'.join(str(p) for p in e['loc'])}: {e['msg']}" for e in exc.errors()
            )
            raise InvalidParameterError(f"invalid training parameters: {msgs}") from exc


def build_model(params: ModelParams) -> PhaseEncoder | ChunkedPlaceEncoder:
    """An unfitted estimator for ``params``."""
    common: dict[str, Any] = dict(
        n_patterns=params.n_patterns,
        periods=params.periods,
        rho=params.rho,
        gamma=params.gamma,
        trainer=params.trainer,
        C=params.C,
        decode=params.decode,
        beam_width=params.beam_width,
        dtype=params.dtype,
        random_state=params.random_state,
        code=params.code,
        code_ratio=params.code_ratio,
        code_exponent=params.code_exponent,
        n_components=params.n_components,
        whiten_power=params.whiten_power,
        temperature=params.temperature,
        auto_width=params.auto_width,
    )
    if params.n_chunks == 1:
        return PhaseEncoder(**common, n_jobs=params.n_jobs, search=params.search)
    return ChunkedPlaceEncoder(
        n_chunks=params.n_chunks,
        chunk_rho=params.chunk_rho,
        top_chunks=params.top_chunks,
        n_jobs=params.n_jobs,
        **common,
    )

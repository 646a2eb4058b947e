"""The training options of a route upload (``POST /v1/maps/{name}/routes`` form fields).

Every field is optional: an unset field takes the server's default. The static bounds here
are the ones the server enforces (``service.encoding.ModelParams`` and the image extractor
configs; a test keeps them equal), so the OpenAPI schema and a client refuse what the server
would refuse before anything is uploaded. Bounds that depend on the route itself (periods
against the number of frames, chunks against frames, extractor fields against each other)
are checked by the server before it answers 202.
"""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import Field, field_validator

from service.wire.base import Request

MAX_PATTERNS = 16  # phase encoders k chosen automatically
MAX_PERIODS = 64  # explicit periods τ1…τk (a product beyond 2^63 frames is meaningless)
MAX_PERIOD = 2**31 - 1
MAX_SEED = 2**32 - 1  # numpy / scikit-learn seeds
Trainer = Literal["logreg", "svm", "ridge", "torch", "prototype"]
EncoderPreset = Literal["paper", "ridge", "robust", "residue", "drive"]  # service.encoding.presets
DecodeMode = Literal["joint", "argmax"]
StorageDtype = Literal["float64", "float32", "float16", "int8", "binary"]
ExtractorKind = Literal["patchnorm", "hog", "cnn"]
Period = Annotated[int, Field(ge=2, le=MAX_PERIOD)]
EXTRACTOR_FIELDS = ("preset", "width", "height", "patch", "orientations", "pixels_per_cell",
                    "cells_per_block")  # fmt: skip
DEFAULT_EXTRACTOR_KIND: ExtractorKind = "cnn"  # service.imaging's default (a test keeps them equal)
# fields about the upload itself rather than the model: kept out of training_params()
UPLOAD_FIELDS = ("allow_dimension_change", "force")


class TrainingOptions(Request):
    """Training (and, for image archives, extractor) options; ``None`` = the server's default."""

    encoder_preset: EncoderPreset | None = Field(
        None, description="named encoder configuration; the fields below override it. Unset: "
        "the server's default (robust), or paper when an option only the paper's code uses is "
        "set (n_patterns, periods, rho, gamma, C, a trainer other than "
        "prototype); the version records the preset used",
    )  # fmt: skip
    n_patterns: int | None = Field(None, ge=1, le=MAX_PATTERNS, description="phase encoders k")
    periods: list[Period] | None = Field(
        None, min_length=1, max_length=MAX_PERIODS,
        description="explicit periods τ1…τk (product ≥ frames; a form field takes '60,60')",
    )  # fmt: skip
    rho: float | None = Field(None, gt=0.0, le=1.0, description="fraction of columns per encoder")
    gamma: float | None = Field(None, ge=1.0, allow_inf_nan=False,
                                description="L1 bound of the pattern weights (default √d')")  # fmt: skip
    trainer: Trainer | None = Field(None, description="linear trainer (logreg = the paper's)")
    C: float | None = Field(None, gt=0.0, allow_inf_nan=False,
                            description="inverse regularisation strength")  # fmt: skip
    decode: DecodeMode | None = None
    beam_width: int | None = Field(None, ge=1, le=100_000)
    dtype: StorageDtype | None = Field(None, description="stored weight precision")
    n_chunks: int | None = Field(None, ge=1, le=100_000, description="1 = no chunking")
    chunk_rho: float | None = Field(None, gt=0.0, le=1.0)
    top_chunks: int | None = Field(None, ge=1, le=100_000)
    random_state: int | None = Field(None, ge=0, le=MAX_SEED)
    frame_spacing_m: float | None = Field(
        None, gt=0.0, le=10_000.0, allow_inf_nan=False,
        description="metres between consecutive frames of the route, recorded with the version: "
        "vehicles may then send odometry in metres",
    )  # fmt: skip
    extractor: ExtractorKind | None = Field(None, description="image archives: how frames "
                                            "become descriptors (default cnn)")  # fmt: skip
    preset: str | None = Field(None, min_length=1, max_length=100,
                               description="cnn preset, e.g. lite0-b4 (implies extractor=cnn)")  # fmt: skip
    width: int | None = Field(None, ge=4, le=4096, description="frames resized to width×height")
    height: int | None = Field(None, ge=4, le=4096)
    patch: int | None = Field(None, ge=1, le=1024, description="patchnorm patch side")
    orientations: int | None = Field(None, ge=2, le=32, description="hog")
    pixels_per_cell: int | None = Field(None, ge=2, le=256, description="hog")
    cells_per_block: int | None = Field(None, ge=1, le=16, description="hog")
    allow_dimension_change: bool | None = Field(
        None, description="accept a descriptor width other than the active version's (its "
        "clients must change too); refused with 409 otherwise",
    )  # fmt: skip
    force: bool | None = Field(
        None, description="train even if this route was uploaded before with the same parameters"
    )

    @field_validator("periods", mode="before")
    @classmethod
    def _split_periods(cls, value: Any) -> Any:
        """``"60,60"``, ``"60x60"`` or repeated form fields → a list (empty → automatic)."""
        parts = [value] if isinstance(value, str) else value
        if isinstance(parts, list | tuple) and any(isinstance(p, str) for p in parts):
            split = [q.strip() for p in parts for q in str(p).replace("x", ",").split(",")]
            items = [q for q in split if q]
            return items or None
        return value

    def training_params(self) -> dict[str, Any]:
        """The set training fields (for ``ModelParams``)."""
        return self.model_dump(exclude_none=True,
                               exclude={"extractor", *EXTRACTOR_FIELDS, *UPLOAD_FIELDS})  # fmt: skip

    def extractor_config(self) -> dict[str, Any] | None:
        """The image extractor config, or ``None`` when no extractor field is set."""
        fields = self.model_dump(exclude_none=True, include=set(EXTRACTOR_FIELDS))
        if self.extractor is None and not fields:
            return None
        kind = self.extractor or ("cnn" if self.preset else DEFAULT_EXTRACTOR_KIND)
        return {"kind": kind, **fields}

    def upload_flags(self) -> dict[str, bool]:
        """The upload-level flags (unset = false)."""
        return {k: bool(getattr(self, k)) for k in UPLOAD_FIELDS}

    def form(self) -> dict[str, str]:
        """The multipart form fields (only the options that were set)."""
        out: dict[str, str] = {}
        for key, value in self.model_dump(exclude_none=True).items():
            if key == "periods":
                out[key] = ",".join(str(p) for p in value)
            else:
                out[key] = str(value).lower() if isinstance(value, bool) else str(value)
        return out

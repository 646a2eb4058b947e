"""Training parameters as one validated object, and the model they describe.

The CLI, the API and the queue all describe a training run with :class:`ModelParams`; an
unchunked route (``n_chunks = 1``) gets a :class:`PhaseEncoder`, a longer one a
:class:`ChunkedPlaceEncoder`.
"""

from __future__ import annotations

import importlib.util
from functools import lru_cache
from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError

from service.encoding.chunked import ChunkedPlaceEncoder
from service.encoding.encoder import PhaseEncoder
from service.errors import InvalidParameterError

Period = Annotated[int, Field(ge=2, le=2**31 - 1)]

PAPER_TRAINER = "logreg"  # LIBLINEAR L2 logistic regression, C = 4, as in the paper's code


@lru_cache(maxsize=1)
def default_trainer() -> str:
    """The trainer used when none is named (CLI, REST uploads, demo): the one place to
    change the default.

    ``torch`` when PyTorch is installed (the logistic loss of ``logreg``, all classes at once,
    several times faster), else ``ridge`` (closed form, faster still, slightly less precise).
    The paper's ``logreg`` (:data:`PAPER_TRAINER`) stays available by name.
    """
    return "torch" if importlib.util.find_spec("torch") is not None else "ridge"


class ModelParams(BaseModel):
    """Every training parameter, each with a sensible default."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    n_patterns: int = Field(2, ge=1, le=16, description="number of phase encoders k")
    periods: tuple[Period, ...] | None = Field(
        None, min_length=1, max_length=64, description="explicit periods τ1…τk"
    )
    rho: float = Field(0.5, gt=0.0, le=1.0, description="fraction of columns per encoder")
    gamma: float | None = Field(
        None, ge=1.0, allow_inf_nan=False, description="L1 bound of pattern weights"
    )
    trainer: Literal["logreg", "svm", "ridge", "torch"] = Field(
        default_factory=default_trainer, description="see default_trainer()"
    )
    C: float = Field(4.0, gt=0.0, allow_inf_nan=False, description="inverse regularisation strength")
    decode: Literal["joint", "argmax"] = "joint"
    beam_width: int = Field(64, ge=1, le=100_000)
    dtype: Literal["float64", "float32", "float16", "int8"] = "float32"
    n_chunks: int = Field(1, ge=1, le=100_000, description="1 = no chunking")
    chunk_rho: float | None = Field(None, gt=0.0, le=1.0)
    top_chunks: int = Field(2, ge=1, le=100_000)
    n_jobs: int = Field(
        1, ge=-1, description="parallel chunk processes, or one-vs-rest threads without chunks"
    )
    random_state: int | None = Field(0, ge=0, le=2**32 - 1, description="seed of the trainers")

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
    )
    if params.n_chunks == 1:
        return PhaseEncoder(**common, n_jobs=params.n_jobs)
    return ChunkedPlaceEncoder(
        n_chunks=params.n_chunks,
        chunk_rho=params.chunk_rho,
        top_chunks=params.top_chunks,
        n_jobs=params.n_jobs,
        **common,
    )

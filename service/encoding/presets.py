"""Named encoder configurations: the paper's code, its closed-form ridge variant, the product
default chosen by measurement across conditions, and the codes for drives.

A preset fixes the parameters that define the encoder (trainer, code, front-end, storage);
:class:`service.encoding.factory.ModelParams` starts from one preset and explicit fields
override its fields. Which one (:func:`base_preset`, the same rule for the CLI, REST uploads
and the library):

- ``encoder_preset=NAME`` names it;
- otherwise an option that only the paper's code uses (:data:`PAPER_OPTIONS`: ``n_patterns``,
  ``periods``, ``rho``, ``gamma``, ``C``; ``code="mixed_radix"``; a trainer other than the
  default preset's) starts from ``paper``, so ``--patterns 2 --rho 0.5`` trains the code it
  describes and ``--trainer ridge`` is the ``ridge`` preset, not a ridge over the default's
  projection;
- otherwise (no option, or only options the default uses too: ``n_components``, ``dtype``,
  chunking, …) it is :data:`DEFAULT_PRESET`.

The preset used is recorded (``ModelParams.encoder_preset``), so a stored job or version
says what it was trained with.

- ``paper``: Le & Milford's code: LIBLINEAR logistic regression (``C = 4``), mixed-radix
  digits, ``k = 2``, ``ρ = 0.5``, no projection, float32.
- ``ridge``: the same code with the closed-form ridge trainer (fitted in seconds).
- ``robust``: PCA-256 front-end whitened with power 0.75, ``prototype`` classifiers, int8
  weights, one digit whose period is the route (``k = 1``): one class per frame, i.e. a
  cosine nearest neighbour in the projected space with a softmax over the frames
  (temperature calibrated on the tuning half of Nordland). ``k`` was chosen there among
  1, 2, 3, 4 and 6 at the same storage (``Στ = N``): every extra digit pools far-apart frames
  into one class and loses precision; the width among 64, 128 and 256 components (on the
  tuning half, CNN descriptors: 41.6 % at 128, 52.9 % at 256 within ±5 frames).
- ``residue``: a PCA-128 front-end and the same trainer with the best multi-digit code
  measured: residue digits ``i mod τ_j``, ``k = 2``, ``Στ ≈ N``.

- ``drive``: a code whose bytes grow sub-linearly, for vehicles that send drives (streams,
  ``/v1/localize/sequence``): residue digits, ``k = 2``, ``Στ = 44·√N`` (capped at ``N``),
  binary class templates (a sign bit per component and a width per column) over the
  PCA-128 front-end. Single frames alias (17 % within ±5 on Nordland winter, adapted); the
  vehicle's motion tells the aliases apart through the sequence filter
  (:mod:`service.encoding.tracking`), whose per-frame cost then does not grow with ``N``.

Measured across seasons on Nordland (summer reference, winter queries) ``robust`` and
``residue`` are far above the mixed-radix presets, which are near chance there. Their storage is
``≈ Στ·n_components`` bytes with biases and scales (about 264 B per frame for ``robust`` at
PCA-256, 136 B at PCA-128: linear in ``N``) plus the fixed projection.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field

PresetName = Literal["paper", "ridge", "robust", "residue", "drive"]
DEFAULT_PRESET: PresetName = "robust"


class EncoderPreset(BaseModel):
    """The encoder-defining subset of the training parameters."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    description: str = Field(exclude=True)
    trainer: Literal["logreg", "svm", "ridge", "torch", "prototype"]
    C: float = 4.0
    code: Literal["mixed_radix", "residue"]
    code_ratio: float = 1.0
    code_exponent: float = 1.0
    n_patterns: int
    rho: float
    n_components: int | None
    whiten_power: float = 0.75
    dtype: Literal["float64", "float32", "float16", "int8", "binary"]
    temperature: float | None = None

    def params(self) -> dict[str, Any]:
        """The preset's training parameters (for ``ModelParams`` or an estimator)."""
        return self.model_dump()


PRESETS: dict[str, EncoderPreset] = {
    "paper": EncoderPreset(
        description="the paper's code: logreg C=4, mixed radix, k=2, rho=0.5, float32",
        trainer="logreg", code="mixed_radix", n_patterns=2, rho=0.5, n_components=None,
        dtype="float32",
    ),
    "ridge": EncoderPreset(
        description="the paper's code with the closed-form ridge trainer (fast)",
        trainer="ridge", code="mixed_radix", n_patterns=2, rho=0.5, n_components=None,
        dtype="float32",
    ),
    "robust": EncoderPreset(
        description="PCA-256 whitened 0.75, one int8 prototype per frame (k=1, a softmax "
        "over the frames): robust across conditions (the default)",
        trainer="prototype", code="residue", code_ratio=1.0, n_patterns=1, rho=1.0,
        n_components=256, whiten_power=0.75, dtype="int8", temperature=0.028,
    ),
    "residue": EncoderPreset(
        description="as robust, with residue digits i mod tau_j, k=2, sum of periods = N",
        trainer="prototype", code="residue", code_ratio=1.0, n_patterns=2, rho=1.0,
        n_components=128, whiten_power=0.75, dtype="int8", temperature=0.07,
    ),
    "drive": EncoderPreset(
        description="a sub-linear code for drives: residue digits i mod tau_j, k=2, "
        "sum of periods = 44 sqrt(N), binary class templates over PCA-128 (a vehicle's "
        "motion tells the aliases apart: streams, /localize/sequence)",
        trainer="prototype", code="residue", code_ratio=44.0, code_exponent=0.5, n_patterns=2,
        rho=1.0, n_components=128, whiten_power=0.75, dtype="binary", temperature=0.05,
    ),
}  # fmt: skip


def preset(name: str) -> EncoderPreset:
    """The preset called ``name`` (``KeyError`` lists the known names)."""
    try:
        return PRESETS[name]
    except KeyError:
        known = sorted(PRESETS)
        raise KeyError(f"unknown encoder preset {name!r}; choose one of {known}") from None


# fields that only the paper's code uses: given without a preset, they start from PAPER_PRESET
PAPER_OPTIONS: tuple[str, ...] = ("n_patterns", "periods", "rho", "gamma", "C")
PAPER_PRESET: PresetName = "paper"


def base_preset(given: Mapping[str, Any]) -> tuple[str, tuple[str, ...]]:
    """The preset that training parameters ``given`` start from, and the fields that chose
    ``paper`` (empty unless they did): the named ``encoder_preset``; else ``paper`` when a
    field of :data:`PAPER_OPTIONS`, ``code="mixed_radix"`` or a trainer other than the default
    preset's is given (not ``None``); else :data:`DEFAULT_PRESET`."""
    named = given.get("encoder_preset")
    if named is not None:
        return str(named), ()
    default = PRESETS[DEFAULT_PRESET]
    chose = [k for k in PAPER_OPTIONS if given.get(k) is not None]
    if given.get("code") == "mixed_radix" and default.code != "mixed_radix":
        chose.append("code")
    if given.get("trainer") not in (None, default.trainer):
        chose.append("trainer")
    return (PAPER_PRESET, tuple(chose)) if chose else (DEFAULT_PRESET, ())


def describe_presets() -> str:
    """One line per preset, for ``--help`` texts."""
    return "; ".join(f"{name}: {p.description}" for name, p in PRESETS.items())

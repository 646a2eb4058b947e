"""The methods ``gridplace bench drive`` compares, by name.

- ``exact-nn``: every reference descriptor, float32 (:class:`service.encoding.ExactNN`);
- ``pq-mM``: product quantisation with ``M`` sub-quantisers (faiss; ``M`` divides ``d``);
- ``residue-rR`` / ``residue-kK-rR``: the ``residue`` preset with ``K`` digits (default 2)
  and automatic periods whose sum is ``Στ ≈ R·N``;
- any encoder preset by its name (``robust``, ``ridge``, ``residue``, ``paper``, ``drive``).

Each is an unfitted model with ``fit``, ``frame_log_scores`` and ``footprint``.
"""

from __future__ import annotations

import re
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from service.encoding import ExactNN, ModelParams, PQIndex, build_model
from service.encoding.pq import faiss_available
from service.encoding.presets import PRESETS
from service.errors import InvalidParameterError

DEFAULT_METHODS: tuple[str, ...] = (
    "exact-nn", "pq-m64", "robust", "residue-r0.1", "residue-r0.034", "residue-k3-r0.013",
    "ridge",
)  # fmt: skip
_PQ = re.compile(r"pq-m(\d+)$")
_RESIDUE = re.compile(r"residue(?:-k(\d+))?-r([0-9.]+)$")


@dataclass(frozen=True)
class DriveMethod:
    name: str
    build: Callable[[], Any] = field(compare=False, repr=False)
    params: dict[str, Any] = field(default_factory=dict)


def method(name: str) -> DriveMethod:
    """The method called ``name`` (see module doc); :class:`InvalidParameterError` names the
    forms it accepts."""
    if name == "exact-nn":
        return DriveMethod(name, ExactNN, {"kind": "exact_nn", "dtype": "float32"})
    if m := _PQ.match(name):
        if not faiss_available():
            raise InvalidParameterError(f"{name} needs faiss (pip install '.[faiss]')")
        sub = int(m.group(1))
        return DriveMethod(name, lambda: PQIndex(n_subquantizers=sub),
                           {"kind": "pq", "n_subquantizers": sub})  # fmt: skip
    if m := _RESIDUE.match(name):
        k = int(m.group(1) or 2)
        try:
            ratio = float(m.group(2))
        except ValueError as exc:
            raise InvalidParameterError(f"{name}: {m.group(2)!r} is not a code ratio") from exc
        return _preset_method(name, encoder_preset="residue", n_patterns=k, code_ratio=ratio)
    if name in PRESETS:
        return _preset_method(name, encoder_preset=name)
    raise InvalidParameterError(
        f"unknown method {name!r}: exact-nn, pq-mM, residue-rR, residue-kK-rR or a preset "
        f"({', '.join(sorted(PRESETS))})"
    )


def _preset_method(name: str, **given: Any) -> DriveMethod:
    params = ModelParams.parse(**given)
    return DriveMethod(name, lambda: build_model(params),
                       {"kind": "gridplace", **params.model_dump(mode="json")})  # fmt: skip


def methods(names: str | None) -> list[DriveMethod]:
    """The comma-separated ``names`` (default :data:`DEFAULT_METHODS` and the ``drive``
    preset)."""
    if names:
        chosen = [n.strip() for n in names.split(",") if n.strip()]
    else:
        chosen = [*DEFAULT_METHODS, "drive"]
    if len(set(chosen)) != len(chosen):
        raise InvalidParameterError(f"a method is named twice in {chosen}")
    return [method(n) for n in chosen]


def footprint(model: Any) -> dict[str, Any]:
    """The fitted model's bytes: total, and per component (as the model reports them)."""
    fp = model.footprint()
    return {
        "bytes": int(fp.actual_bytes),
        "components": {k: int(c.actual_bytes) for k, c in fp.components.items()},
    }

"""A phase encoder's arrays and metadata as stored in an artifact, and back.

The tensors (digit classifiers, front end, inverted file, append tallies, condition
whitening and statistics) go into the artifact's array file under ``prefix``; the metadata
(frames, features, periods, traversals, condition keys) into its JSON.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from service.encoding import appending
from service.encoding.conditions import conditions_from_arrays, conditions_to_arrays
from service.encoding.digit_classifier import DigitClassifier
from service.encoding.front_end import FrontEnd
from service.encoding.inverted_file import InvertedFile
from service.encoding.phases import validate_periods
from service.encoding.residue import validate_residue_periods

if TYPE_CHECKING:
    from service.encoding.encoder import PhaseEncoder


def to_arrays(
    model: PhaseEncoder, width: int, prefix: str = ""
) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """A fitted encoder's arrays and metadata; ``width``: the rows its digits see."""
    arrays: dict[str, np.ndarray] = {}
    for j, dc in enumerate(model.digits_):
        arrays.update(dc.to_arrays(f"{prefix}enc.{j}", width))
    if model.normalizer_ is not None:
        arrays.update(model.normalizer_.to_arrays(f"{prefix}norm"))
    if getattr(model, "ivf_", None) is not None:
        arrays.update(model.ivf_.to_arrays(f"{prefix}ivf"))
    meta: dict[str, Any] = {
        "n_frames": model.n_frames_,
        "n_features": model.n_features_in_,
        "periods": list(model.periods_),
        "n_traversals": model.n_traversals_,
    }
    if keys := conditions_to_arrays(getattr(model, "conditions_", None) or {}, arrays, prefix):
        meta["conditions"] = keys
    return arrays, meta


def restore(
    model: PhaseEncoder, arrays: dict[str, np.ndarray], meta: dict[str, Any], prefix: str = ""
) -> None:
    """Set an unfitted encoder's fitted state from :func:`to_arrays`' output."""
    d = int(meta["n_features"])
    n = int(meta["n_frames"])
    if model.code == "residue":
        model.periods_ = validate_residue_periods(meta["periods"], n)
    else:
        model.periods_ = validate_periods(meta["periods"], n)
    model.normalizer_ = FrontEnd.from_arrays(arrays, f"{prefix}norm")
    width = d if model.normalizer_ is None or model.normalizer_.n_outputs is None else int(
        model.normalizer_.n_outputs)  # fmt: skip
    model.digits_ = [
        DigitClassifier.from_arrays(arrays, f"{prefix}enc.{j}", width)
        for j in range(len(model.periods_))
    ]
    model.ivf_ = InvertedFile.from_arrays(arrays, f"{prefix}ivf", n)
    tallies = [appending.ClassTally.from_arrays(arrays, f"{prefix}enc.{j}")
               for j in range(len(model.periods_))]  # fmt: skip
    model.tallies_ = tallies if all(t is not None for t in tallies) else None
    model.whitening_ = appending.ConditionWhitening.from_arrays(arrays, f"{prefix}whiten")
    model.conditions_ = conditions_from_arrays(arrays, meta.get("conditions"), prefix)
    model._set_fitted(n, d, int(meta.get("n_traversals", 1)))
